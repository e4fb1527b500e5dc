#include "simstack/offline/training/training_sample.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "simstack/offline/dataset/viewpoints.h"
#include "simstack/render/depth_renderer.h"
#include "simstack/tsdf/network_input.h"
#include "simstack/tsdf/projective_tsdf.h"

namespace simstack {

TrainingSampleBuilder::TrainingSampleBuilder(const CvaeConfig& config, const PinholeCamera& camera,
                                             bool sensor_noise, double overhead_share,
                                             SensorModel sensor)
    : config_(config),
      camera_(camera),
      noise_(sensor_noise),
      overhead_share_(overhead_share),
      sensor_(sensor) {
  config_.validate();
  camera_.validate();
}

TrainingSample TrainingSampleBuilder::build(const SceneRecord& record, std::mt19937_64& rng) const {
  // With no overhead share no extra draw is made: the stream is that of the side views alone.
  const bool overhead = overhead_share_ > 0.0 &&
                        std::uniform_real_distribution<double>(0.0, 1.0)(rng) < overhead_share_;
  const Transform T =
      sampleViewpoint(record.scene.surfaceCentroid(),
                      overhead ? ViewpointRange::overhead() : ViewpointRange(), rng);
  return build(record, T, rng());
}

TrainingSample TrainingSampleBuilder::build(const SceneRecord& rec, const Transform& T_table_camera,
                                            uint64_t noise_seed) const {
  const GridSpec& stored = rec.grid;
  if (stored.resolution != config_.resolution ||
      std::abs(stored.extent_m() - config_.extent_m) > 1e-9) {
    throw std::invalid_argument(
        "dataset grid (" + std::to_string(stored.resolution) + "^3, " +
        std::to_string(stored.extent_m()) + " m) does not match the model (" +
        std::to_string(config_.resolution) + "^3, " + std::to_string(config_.extent_m) + " m)");
  }
  const DepthRenderer renderer(rec.scene);
  const RenderResult view = renderer.render(
      camera_, T_table_camera,
      noise_ ? SensorNoiseConfig::preset(sensor_, noise_seed) : SensorNoiseConfig());
  // Re-centre on what the camera sees, snapped to the stored lattice so GT shifts exactly.
  const double voxel = stored.voxel_size_m;
  const Vec2 stored_centre =
      stored.origin_table.head<2>() + Vec2::Constant(0.5 * stored.extent_m());
  const Vec2 centre = visiblePileCentre(view.depth, camera_, T_table_camera, stored_centre,
                                        0.5 * stored.extent_m());
  const int sx = static_cast<int>(std::lround((centre.x() - stored_centre.x()) / voxel));
  const int sy = static_cast<int>(std::lround((centre.y() - stored_centre.y()) / voxel));
  TrainingSample s;
  s.T_table_camera = T_table_camera;
  s.grid = stored;
  s.grid.origin_table += Vec3(sx * voxel, sy * voxel, 0.0);
  ProjectiveTsdfConfig tc;
  tc.truncation_m = config_.truncation_m();
  ProjectiveTsdf partial(s.grid, tc);
  partial.integrate(view.depth, camera_, T_table_camera);
  s.partial = partialChannels(partial.tsdf(), partial.weight(), tc.truncation_m);
  const int r = stored.resolution;
  const size_t n = static_cast<size_t>(r) * r * r;
  s.tsdf.assign(n, 1.0f);
  s.votes.assign(3 * n, 0.0f);
  std::vector<uint8_t> labels(n, 0);
  const float inv_tau = static_cast<float>(1.0 / config_.truncation_m());
  for (int z = 0; z < r; ++z) {
    for (int y = 0; y < r; ++y) {
      for (int x = 0; x < r; ++x) {
        const int ox = x + sx, oy = y + sy;
        if (ox < 0 || oy < 0 || ox >= r || oy >= r) continue;  // outside the stored grid: free
        const size_t i = static_cast<size_t>(stored.linear(x, y, z));
        const size_t j = static_cast<size_t>(stored.linear(ox, oy, z));
        s.tsdf[i] = std::clamp(rec.ground_truth.tsdf.data[j] * inv_tau, -1.0f, 1.0f);
        for (int c = 0; c < 3; ++c) s.votes[c * n + i] = rec.ground_truth.votes.data[j][c];
        labels[i] = rec.ground_truth.labels.data[j];
      }
    }
  }
  if (config_.vote_boundary_weight > 0.0)
    s.vote_weight =
        voteBoundaryWeights(labels, r, static_cast<float>(config_.vote_boundary_weight));
  return s;
}

std::vector<float> voteBoundaryWeights(const std::vector<uint8_t>& labels, int r, float boundary) {
  const size_t n = static_cast<size_t>(r) * r * r;
  if (labels.size() != n)
    throw std::invalid_argument("voteBoundaryWeights: " + std::to_string(labels.size()) +
                                " labels for a grid of " + std::to_string(n));
  std::vector<float> weight(n, 1.0f);
  const auto at = [&](int x, int y, int z) {
    return labels[(static_cast<size_t>(z) * r + y) * r + x];
  };
  for (int z = 0; z < r; ++z)
    for (int y = 0; y < r; ++y)
      for (int x = 0; x < r; ++x) {
        const uint8_t k = at(x, y, z);
        if (k == 0) continue;
        bool near = false;
        for (int dz = -2; dz <= 2 && !near; ++dz)
          for (int dy = -2; dy <= 2 && !near; ++dy)
            for (int dx = -2; dx <= 2 && !near; ++dx) {
              const int a = x + dx, b = y + dy, c = z + dz;
              if (a < 0 || b < 0 || c < 0 || a >= r || b >= r || c >= r) continue;
              const uint8_t l = at(a, b, c);
              near = l != 0 && l != k;
            }
        if (near) weight[(static_cast<size_t>(z) * r + y) * r + x] = 1.0f + boundary;
      }
  return weight;
}

}  // namespace simstack
