// Grasp ranking: 64 candidates on a fixed 4-object pile, simulated in H = 1 and H = 3 scene
// hypotheses on 1 and 2 threads (the 1-thread run is the peer of the 2-thread one), with and
// without perturbed copies of the scene, the candidate search alone, and the service's check
// of the target's surface cloud. Counters: pulls simulated per second.
#include <benchmark/benchmark.h>

#include "../test_scenes.h"
#include "simstack/grasping/grasp_ranking.h"
#include "simstack/grasping/grasp_request.h"

using namespace simstack;

namespace {

/// The pile and H - 1 further hypotheses: the same objects shifted by a few millimetres and
/// turned by a few degrees, as the latent samples of the perception differ.
std::vector<std::vector<SuperquadricShape>> hypotheses(int count) {
  std::vector<SuperquadricShape> pile;
  for (const SceneObject& o : test::fourObjectPile().objects) pile.push_back(o.superquadricTable());
  std::vector<std::vector<SuperquadricShape>> out{pile};
  for (int h = 1; h < count; ++h) {
    auto other = pile;
    for (size_t k = 0; k < other.size(); ++k) {
      const double s = (h % 2 ? 1.0 : -1.0) * (1.0 + 0.3 * k);
      other[k].T_table_object.translation() += Vec3(0.003 * s, -0.002 * s, 0.0);
      other[k].T_table_object.linear() =
          other[k].T_table_object.linear() *
          Eigen::AngleAxisd(0.03 * s, Vec3::UnitZ()).toRotationMatrix();
    }
    out.push_back(other);
  }
  return out;
}

constexpr int kTarget = 1;  // the standing cylinder beside the box

}  // namespace

static void BM_RankGrasps(benchmark::State& state) {
  const auto scenes = hypotheses(static_cast<int>(state.range(0)));
  GraspRankingConfig config;
  config.candidates.max_candidates = 64;
  config.threads = static_cast<int>(state.range(1));
  long pulls = 0;
  size_t grasps = 0;
  for (auto _ : state) {
    const GraspRanking r = rankGrasps(scenes, kTarget, {}, config);
    pulls += r.pulls;
    grasps = r.grasps.size();
  }
  state.counters["pulls_per_s"] =
      benchmark::Counter(static_cast<double>(pulls), benchmark::Counter::kIsRate);
  state.counters["grasps"] = static_cast<double>(grasps);
}
BENCHMARK(BM_RankGrasps)
    ->ArgNames({"H", "threads"})
    ->Args({1, 1})
    ->Args({1, 2})
    ->Args({3, 1})
    ->Args({3, 2})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->MinTime(2.0);

// The same ranking (H = 1, 2 threads) with the scene's perturbed copies: copies = 0 is the peer.
static void BM_RankGraspsPerturbed(benchmark::State& state) {
  const auto scenes = hypotheses(1);
  GraspRankingConfig config;
  config.candidates.max_candidates = 64;
  config.threads = 2;
  config.perturbation.copies = static_cast<int>(state.range(0));
  long pulls = 0;
  for (auto _ : state) pulls += rankGrasps(scenes, kTarget, {}, config).pulls;
  state.counters["pulls_per_s"] =
      benchmark::Counter(static_cast<double>(pulls), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_RankGraspsPerturbed)
    ->ArgNames({"copies"})
    ->Arg(0)
    ->Arg(4)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->MinTime(2.0);

static void BM_SuctionCandidates(benchmark::State& state) {
  const auto scene = hypotheses(1).front();
  CandidateConfig config;
  const auto cameras = defaultCameraPositions(scene);
  int sealable = 0;
  for (auto _ : state) sealable = suctionCandidates(scene, kTarget, cameras, config).sealable;
  state.counters["sealable"] = sealable;
}
BENCHMARK(BM_SuctionCandidates)->Unit(benchmark::kMillisecond)->UseRealTime();

// The grasp service's check that a target's surface cloud lies on its superquadric, on N points
// of the target's surface (on: every point passes along the ray from the centre) and on the same
// points 25 cm aside (off: the refused case, every point beyond the bounding sphere and passed
// over without a surface search). Peer: BM_RankGrasps/H:1/threads:2, the ranking it precedes.
static void BM_MeasuredOffTarget(benchmark::State& state) {
  const SuperquadricShape target = hypotheses(1).front()[kTarget];
  const std::vector<Vec3> surface = target.meshObject(48).vertices;
  Points3 cloud;
  const Vec3 aside = state.range(1) ? Vec3(0.25, 0.0, 0.0) : Vec3::Zero();
  while (cloud.size() < static_cast<size_t>(state.range(0)))
    for (const Vec3& v : surface) cloud.push_back(target.T_table_object * v + aside);
  cloud.resize(static_cast<size_t>(state.range(0)));
  bool refused = false;
  for (auto _ : state) refused = !measuredOffTarget(cloud, target).empty();
  state.counters["refused"] = refused;
}
BENCHMARK(BM_MeasuredOffTarget)
    ->ArgNames({"points", "off"})
    ->Args({2000, 0})
    ->Args({2000, 1})
    ->Args({100000, 0})
    ->Args({100000, 1})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

BENCHMARK_MAIN();
