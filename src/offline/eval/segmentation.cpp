#include "simstack/offline/eval/segmentation.h"

#include <algorithm>
#include <limits>
#include <map>
#include <set>
#include <stdexcept>
#include <string>
#include <tuple>

namespace simstack {

SegmentationAgreement segmentationAgreement(const std::vector<int>& truth,
                                            const std::vector<int>& found) {
  if (truth.size() != found.size())
    throw std::invalid_argument("segmentation agreement: " + std::to_string(truth.size()) +
                                " labels against " + std::to_string(found.size()));
  std::map<std::pair<int, int>, long> overlap;
  std::set<int> objects, instances;
  long labelled = 0;
  for (size_t i = 0; i < truth.size(); ++i) {
    if (found[i] >= 0) instances.insert(found[i]);
    if (truth[i] < 0) continue;
    objects.insert(truth[i]);
    ++labelled;
    if (found[i] >= 0) ++overlap[{truth[i], found[i]}];
  }
  // Largest overlap first; ties by labels, so the result does not depend on map order.
  std::vector<std::tuple<long, int, int>> pairs;
  for (const auto& [k, n] : overlap) pairs.emplace_back(n, -k.first, -k.second);
  std::sort(pairs.rbegin(), pairs.rend());
  std::set<int> used_truth, used_found;
  long matched = 0;
  for (const auto& [n, t, f] : pairs) {
    if (used_truth.count(-t) || used_found.count(-f)) continue;
    used_truth.insert(-t);
    used_found.insert(-f);
    matched += n;
  }
  SegmentationAgreement s;
  s.agreement = labelled > 0 ? static_cast<double>(matched) / labelled : 0.0;
  s.objects = static_cast<int>(objects.size());
  s.instances = static_cast<int>(instances.size());
  return s;
}

namespace {

/// Minimum-cost assignment of each of n rows to its own column of an n x m cost matrix,
/// n <= m (shortest augmenting paths with row and column potentials). Returns each row's
/// column.
std::vector<int> minimumCostRows(const std::vector<std::vector<double>>& cost, size_t m) {
  const size_t n = cost.size();
  const double inf = std::numeric_limits<double>::infinity();
  // 1-based: column 0 is the virtual start of each augmenting path.
  std::vector<double> u(n + 1, 0.0), v(m + 1, 0.0);
  std::vector<size_t> row_of(m + 1, 0), previous(m + 1, 0);
  for (size_t i = 1; i <= n; ++i) {
    row_of[0] = i;
    size_t j0 = 0;
    std::vector<double> slack(m + 1, inf);
    std::vector<bool> used(m + 1, false);
    do {
      used[j0] = true;
      const size_t i0 = row_of[j0];
      double delta = inf;
      size_t j1 = 0;
      for (size_t j = 1; j <= m; ++j) {
        if (used[j]) continue;
        const double reduced = cost[i0 - 1][j - 1] - u[i0] - v[j];
        if (reduced < slack[j]) {
          slack[j] = reduced;
          previous[j] = j0;
        }
        if (slack[j] < delta) {
          delta = slack[j];
          j1 = j;
        }
      }
      for (size_t j = 0; j <= m; ++j) {
        if (used[j]) {
          u[row_of[j]] += delta;
          v[j] -= delta;
        } else {
          slack[j] -= delta;
        }
      }
      j0 = j1;
    } while (row_of[j0] != 0);
    do {  // flip the path back to its start
      const size_t j1 = previous[j0];
      row_of[j0] = row_of[j1];
      j0 = j1;
    } while (j0 != 0);
  }
  std::vector<int> out(n, -1);
  for (size_t j = 1; j <= m; ++j)
    if (row_of[j] != 0) out[row_of[j] - 1] = static_cast<int>(j - 1);
  return out;
}

}  // namespace

std::vector<int> maximumWeightAssignment(const std::vector<std::vector<double>>& weight) {
  const size_t rows = weight.size();
  const size_t columns = rows == 0 ? 0 : weight.front().size();
  for (const auto& row : weight)
    if (row.size() != columns)
      throw std::invalid_argument("assignment: rows of " + std::to_string(columns) + " and " +
                                  std::to_string(row.size()) + " weights");
  if (rows == 0 || columns == 0) return std::vector<int>(rows, -1);
  if (rows <= columns) {
    std::vector<std::vector<double>> cost(rows, std::vector<double>(columns));
    for (size_t i = 0; i < rows; ++i)
      for (size_t j = 0; j < columns; ++j) cost[i][j] = -weight[i][j];
    return minimumCostRows(cost, columns);
  }
  std::vector<std::vector<double>> cost(columns, std::vector<double>(rows));  // transposed
  for (size_t i = 0; i < rows; ++i)
    for (size_t j = 0; j < columns; ++j) cost[j][i] = -weight[i][j];
  const std::vector<int> row_of_column = minimumCostRows(cost, rows);
  std::vector<int> out(rows, -1);
  for (size_t j = 0; j < columns; ++j) out[row_of_column[j]] = static_cast<int>(j);
  return out;
}

OverlapScores overlapScores(const std::vector<int>& truth, const std::vector<int>& found) {
  if (truth.size() != found.size())
    throw std::invalid_argument("overlap scores: " + std::to_string(truth.size()) +
                                " labels against " + std::to_string(found.size()));
  std::map<int, long> object_size, instance_size;
  std::map<std::pair<int, int>, long> overlap;
  for (size_t i = 0; i < truth.size(); ++i) {
    if (truth[i] >= 0) ++object_size[truth[i]];
    if (found[i] >= 0) ++instance_size[found[i]];
    if (truth[i] >= 0 && found[i] >= 0) ++overlap[{truth[i], found[i]}];
  }
  OverlapScores s;
  s.objects = static_cast<int>(object_size.size());
  s.instances = static_cast<int>(instance_size.size());
  if (s.objects == 0 || s.instances == 0) {
    const bool none = s.objects == 0 && s.instances == 0;
    s.precision = s.objects > 0 || none ? 1.0 : 0.0;
    s.recall = s.instances > 0 || none ? 1.0 : 0.0;
    s.f_measure = s.detected_075 = none ? 1.0 : 0.0;
    return s;
  }
  std::map<int, size_t> object_index, instance_index;
  for (const auto& [k, n] : object_size) object_index.emplace(k, object_index.size());
  for (const auto& [k, n] : instance_size) instance_index.emplace(k, instance_index.size());
  std::vector<std::vector<double>> f(object_size.size(),
                                     std::vector<double>(instance_size.size(), 0.0));
  std::vector<std::vector<long>> shared(object_size.size(),
                                        std::vector<long>(instance_size.size(), 0));
  for (const auto& [key, n] : overlap) {
    const size_t i = object_index.at(key.first), j = instance_index.at(key.second);
    const double p = static_cast<double>(n) / instance_size.at(key.second);
    const double r = static_cast<double>(n) / object_size.at(key.first);
    shared[i][j] = n;
    f[i][j] = 2 * p * r / (p + r);
  }
  const std::vector<int> match = maximumWeightAssignment(f);
  long matched = 0, object_total = 0, instance_total = 0;
  int detected = 0;
  for (size_t i = 0; i < match.size(); ++i) {
    if (match[i] < 0) continue;
    matched += shared[i][match[i]];
    if (f[i][match[i]] > 0.75) ++detected;
  }
  for (const auto& [k, n] : object_size) object_total += n;
  for (const auto& [k, n] : instance_size) instance_total += n;
  s.precision = static_cast<double>(matched) / instance_total;
  s.recall = static_cast<double>(matched) / object_total;
  s.f_measure = matched > 0 ? 2 * s.precision * s.recall / (s.precision + s.recall) : 0.0;
  s.detected_075 = static_cast<double>(detected) / s.objects;
  return s;
}

}  // namespace simstack
