#include "simstack/eval/segmentation.h"

#include <algorithm>
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

}  // namespace simstack
