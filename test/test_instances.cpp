// Hough voting against synthetic vote fields whose centres are known exactly.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <functional>
#include <limits>
#include <map>
#include <random>
#include <string>

#include "simstack/instances/hough_voting.h"
#include "simstack/instances/surface_instances.h"
#include "simstack/instances/surface_segments.h"
#include "simstack/render/depth_renderer.h"

namespace simstack {
namespace {

struct Ball {
  Vec3 centre;
  double radius;
};

/// TSDF (min over balls) and the ideal vote field of non-overlapping balls.
void ballFields(const GridSpec& g, const std::vector<Ball>& balls, Grid3<float>* tsdf,
                Grid3<Vec3f>* votes) {
  *tsdf = Grid3<float>(g, 0.06f);
  *votes = Grid3<Vec3f>(g, Vec3f::Zero());
  for (int z = 0; z < g.resolution; ++z)
    for (int y = 0; y < g.resolution; ++y)
      for (int x = 0; x < g.resolution; ++x) {
        const Vec3 p = g.voxelCentre(x, y, z);
        for (const Ball& b : balls) {
          const double d = (p - b.centre).norm() - b.radius;
          if (d < tsdf->at(x, y, z)) {
            tsdf->at(x, y, z) = static_cast<float>(d);
            if (d <= 0) votes->at(x, y, z) = (b.centre - p).normalized().cast<float>();
          }
        }
      }
}

/// k balls of 2.5-4 voxels radius at random non-touching places in a 32^3 grid.
std::vector<Ball> randomBalls(const GridSpec& g, int k, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> pos(0.15, 0.85), rad(2.5, 4.0);
  std::vector<Ball> balls;
  while (static_cast<int>(balls.size()) < k) {
    Ball b{g.origin_table + g.extent_m() * Vec3(pos(rng), pos(rng), pos(rng)),
           rad(rng) * g.voxel_size_m};
    bool ok = true;
    for (const Ball& o : balls)
      ok = ok && (o.centre - b.centre).norm() > o.radius + b.radius + 1.5 * g.voxel_size_m;
    if (ok) balls.push_back(b);
  }
  return balls;
}

/// The distance from each ball's centre to the nearest centre found, in voxels.
std::vector<double> centreErrorsVox(const GridSpec& g, const std::vector<Ball>& balls,
                                    const InstanceSegmentation& seg) {
  std::vector<double> errors;
  for (const Ball& b : balls) {
    double best = 1e9;
    for (const Vec3& c : seg.centres_table) best = std::min(best, (c - b.centre).norm());
    errors.push_back(best / g.voxel_size_m);
  }
  return errors;
}

TEST(HoughVoting, RecoversOneToEightCentresWithinOneVoxel) {
  const GridSpec g = GridSpec::sceneGrid(Vec2(0.1, -0.2), 0.64, 32);
  std::mt19937_64 rng(3);
  for (int k = 1; k <= 8; ++k) {
    const std::vector<Ball> balls = randomBalls(g, k, rng);
    Grid3<float> tsdf;
    Grid3<Vec3f> votes;
    ballFields(g, balls, &tsdf, &votes);
    const InstanceSegmentation seg = houghInstances(tsdf, votes);
    ASSERT_EQ(seg.size(), k) << "k = " << k;
    for (double e : centreErrorsVox(g, balls, seg)) EXPECT_LT(e, 1.0) << "k = " << k;
    // Every occupied voxel gets the instance whose centre is its ball's.
    for (int i = 0; i < g.voxelCount(); ++i) {
      if (tsdf.data[i] > 0) {
        EXPECT_EQ(seg.labels.data[i], -1);
        continue;
      }
      const Vec3i v = g.unravel(i);
      const Vec3 p = g.voxelCentre(v.x(), v.y(), v.z());
      ASSERT_GE(seg.labels.data[i], 0);
      const Vec3 c = seg.centres_table[seg.labels.data[i]];
      double owner = 1e9;
      for (const Ball& b : balls)
        if ((p - b.centre).norm() <= b.radius) owner = (c - b.centre).norm();
      EXPECT_LT(owner, g.voxel_size_m);
    }
  }
}

/// The fine-cell counts of Hough voting computed the plain way, as the reference: each occupied
/// voxel's ray starts at the voxel's centre and is stepped one fine cell at a time along its
/// vote (Amanatides & Woo, parameters accumulated), into a std::map; a ray stops on entering
/// its (tolerance + 1)-th free voxel in a row or on leaving the grid, and only cells of occupied
/// voxels are counted. Returns the counts; `visits` gets every cell stepped through.
std::map<std::array<int, 3>, int> referenceCounts(const Grid3<float>& tsdf,
                                                  const Grid3<Vec3f>& votes, int ref, int tolerance,
                                                  size_t* visits) {
  const GridSpec& g = tsdf.spec;
  const int r = g.resolution;
  std::map<std::array<int, 3>, int> counts;
  *visits = 0;
  for (int i = 0; i < g.voxelCount(); ++i) {
    if (tsdf.data[i] > 0 || votes.data[i].norm() <= 1e-3f) continue;
    const Vec3 d = (votes.data[i] / votes.data[i].norm()).cast<double>();  // as houghInstances
    const Vec3 p = (g.unravel(i).cast<double>() + Vec3::Constant(0.5)) * ref;
    int cell[3], step[3];
    double t_max[3], t_delta[3];
    for (int a = 0; a < 3; ++a) {
      cell[a] = static_cast<int>(std::floor(p[a]));
      step[a] = d[a] > 1e-12 ? 1 : d[a] < -1e-12 ? -1 : 0;
      t_delta[a] = step[a] != 0 ? 1.0 / std::abs(d[a]) : 1e300;
      t_max[a] = step[a] > 0   ? (cell[a] + 1 - p[a]) * t_delta[a]
                 : step[a] < 0 ? (p[a] - cell[a]) * t_delta[a]
                               : 1e300;
    }
    int outside = 0, voxel = -1;
    while (true) {
      const Vec3i v(cell[0] / ref, cell[1] / ref, cell[2] / ref);
      if (cell[0] < 0 || cell[1] < 0 || cell[2] < 0 || v.x() >= r || v.y() >= r || v.z() >= r)
        break;
      const int index = g.linear(v.x(), v.y(), v.z());
      if (index != voxel) {
        voxel = index;
        outside = tsdf.data[index] <= 0 ? 0 : outside + 1;
        if (outside > tolerance) break;
      }
      ++*visits;
      if (tsdf.data[index] <= 0) ++counts[{cell[0], cell[1], cell[2]}];
      int a = 0;  // the smallest t_max; ties to the later axis
      for (int b = 1; b < 3; ++b)
        if (t_max[b] <= t_max[a]) a = b;
      cell[a] += step[a];
      t_max[a] += t_delta[a];
    }
  }
  return counts;
}

TEST(HoughVoting, FineCountsMatchAPlainTraversal) {
  // Noisy votes (every direction, no exact ties) and some along the axes, on balls and on
  // scattered occupied voxels: the cells above each threshold and the cells stepped through
  // equal the reference.
  const GridSpec g = GridSpec::sceneGrid(Vec2(0, 0), 0.64, 24);
  std::mt19937_64 rng(11);
  Grid3<float> tsdf;
  Grid3<Vec3f> votes;
  ballFields(g, randomBalls(g, 4, rng), &tsdf, &votes);
  std::normal_distribution<float> noise(0.0f, 0.4f);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  std::uniform_int_distribution<int> axis(0, 2);
  for (size_t i = 0; i < votes.data.size(); ++i) {
    if (uniform(rng) < 0.03) tsdf.data[i] = -0.01f;  // scattered occupied voxels
    if (tsdf.data[i] > 0) continue;
    votes.data[i] += Vec3f(noise(rng), noise(rng), noise(rng));
    if (uniform(rng) < 0.1) {
      // Some votes along an axis, exactly or but for a component too small to move the ray:
      // with an even refinement their rays run along cell boundaries.
      Vec3f v = Vec3f::Zero();
      v[axis(rng)] = uniform(rng) < 0.5 ? 1.0f : -1.0f;
      if (uniform(rng) < 0.5) v[(axis(rng) + 1) % 3] = uniform(rng) < 0.5 ? 1e-14f : -1e-14f;
      votes.data[i] = v;
    }
  }
  for (const int ref : {1, 2, 3, 4, 5, 8}) {
    for (const int tolerance : {0, 1, 2}) {
      size_t visits = 0;
      const std::map<std::array<int, 3>, int> counts =
          referenceCounts(tsdf, votes, ref, tolerance, &visits);
      for (const int mu : {0, 2, 4, 9}) {
        HoughConfig config;
        config.refinement = ref;
        config.outside_tolerance_vox = tolerance;
        config.min_traversals = mu;
        const InstanceSegmentation seg = houghInstances(tsdf, votes, config);
        int above = 0;
        for (const auto& [cell, n] : counts) above += n > mu;
        EXPECT_EQ(seg.candidate_cells, above)
            << "ref " << ref << " tol " << tolerance << " mu " << mu;
        EXPECT_EQ(seg.traversals, visits) << "ref " << ref << " tol " << tolerance;
      }
    }
  }
}

TEST(HoughVoting, SeparatesCentresCloserThanTheMeanShiftCell) {
  // Two balls 9.5 cm apart (bandwidth 7 cm) whose centres share one 7 cm cell of the table
  // frame: a single mean-shift seed per such cell would settle between them.
  const GridSpec g = GridSpec::sceneGrid(Vec2(0.1, 0.1), 0.64, 32);
  const std::vector<Ball> balls = {{Vec3(0.0751, 0.0751, 0.0751), 0.04},
                                   {Vec3(0.1299, 0.1299, 0.1299), 0.04}};
  Grid3<float> tsdf;
  Grid3<Vec3f> votes;
  ballFields(g, balls, &tsdf, &votes);
  HoughConfig config;
  config.bandwidth_m = 0.07;
  const InstanceSegmentation seg = houghInstances(tsdf, votes, config);
  ASSERT_EQ(seg.size(), 2);
  for (double e : centreErrorsVox(g, balls, seg)) EXPECT_LT(e, 1.0);
}

TEST(HoughVoting, WorksAtR64AndIsSparse) {
  const GridSpec g = GridSpec::sceneGrid(Vec2(0, 0), 0.64, 64);
  std::mt19937_64 rng(5);
  const std::vector<Ball> balls = randomBalls(g, 4, rng);
  Grid3<float> tsdf;
  Grid3<Vec3f> votes;
  ballFields(g, balls, &tsdf, &votes);
  const InstanceSegmentation seg = houghInstances(tsdf, votes);
  EXPECT_EQ(seg.size(), 4);
  EXPECT_GT(seg.traversals, 0u);
  EXPECT_LT(static_cast<double>(seg.candidate_cells), 0.001 * 640.0 * 640 * 640);
  // Sparse: the counts take a small fraction of a dense 16-bit array over the fine grid.
  const double dense_bytes = 2.0 * std::pow(64.0 * HoughConfig().refinement, 3);
  EXPECT_LT(static_cast<double>(seg.count_bytes), 0.05 * dense_bytes);
}

TEST(HoughVoting, ARadiusFarBelowTheVotesSpreadIsRefusedNotMinutesLong) {
  // A ball whose votes point anywhere, every traversed cell a centre vote, and a 1 mm radius:
  // each voxel's votes their own centre (some 2000). Refused, the radius named, before the
  // assignment.
  const GridSpec g = GridSpec::sceneGrid(Vec2(0, 0), 0.64, 32);
  Grid3<float> tsdf;
  Grid3<Vec3f> votes;
  ballFields(g, {{g.origin_table + Vec3(0.32, 0.32, 0.2), 0.16}}, &tsdf, &votes);
  std::mt19937_64 rng(9);
  std::normal_distribution<float> n(0.0f, 1.0f);
  for (Vec3f& v : votes.data)
    if (!v.isZero()) v = Vec3f(n(rng), n(rng), n(rng)).normalized();
  HoughConfig config;
  config.refinement = 8;
  config.min_traversals = 0;
  config.bandwidth_m = 0.001;
  try {
    houghInstances(tsdf, votes, config);
    ADD_FAILURE() << "a 1 mm radius over scattered votes was accepted";
  } catch (const TooManyHoughCentres& e) {
    EXPECT_NE(std::string(e.what()).find("radius of 0.001 m (hough.bandwidth_m"), std::string::npos)
        << e.what();
  }
}

TEST(HoughVoting, EmptySceneAndBadInput) {
  const GridSpec g = GridSpec::sceneGrid(Vec2(0, 0), 0.64, 16);
  const InstanceSegmentation empty =
      houghInstances(Grid3<float>(g, 0.06f), Grid3<Vec3f>(g, Vec3f::Zero()));
  EXPECT_EQ(empty.size(), 0);
  GridSpec other = g;
  other.resolution = 8;
  EXPECT_THROW(houghInstances(Grid3<float>(g, 0.06f), Grid3<Vec3f>(other, Vec3f::Zero())),
               std::invalid_argument);
  // A weight that is not a finite number would leave voxels with no centre; it is refused by
  // name before any voxel is touched.
  Grid3<float> tsdf(g, 0.06f);
  for (int i = 0; i < 50; ++i) tsdf.data[2000 + i] = -0.01f;
  for (double gamma : {std::nan(""), std::numeric_limits<double>::infinity(), 1e308, -1.0}) {
    HoughConfig config;
    config.gamma = gamma;
    try {
      houghInstances(tsdf, Grid3<Vec3f>(g, Vec3f(1, 0, 0)), config);
      ADD_FAILURE() << "gamma " << gamma << " accepted";
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find("hough.gamma"), std::string::npos) << e.what();
    }
  }
  HoughConfig no_bandwidth;
  no_bandwidth.bandwidth_m = std::nan("");
  EXPECT_THROW(no_bandwidth.validate(), std::invalid_argument);
  // A centre no voxel chose is no instance: the least size is one voxel.
  HoughConfig empty_instances;
  empty_instances.min_instance_voxels = 0;
  EXPECT_THROW(empty_instances.validate(), std::invalid_argument);
  // Votes are unit directions: a least norm of 1 or more would leave every scene empty.
  for (double norm : {1.0, 2.0, std::nan(""), -0.1}) {
    HoughConfig config;
    config.min_vote_norm = norm;
    EXPECT_THROW(config.validate(), std::invalid_argument) << "min_vote_norm " << norm;
  }
  // A grid without a size or a place would leave every voxel with no centre: refused.
  const std::vector<std::function<void(GridSpec&)>> bends = {
      [](GridSpec& s) { s.voxel_size_m = 0; }, [](GridSpec& s) { s.voxel_size_m = std::nan(""); },
      [](GridSpec& s) { s.origin_table.x() = std::nan(""); }};
  for (const auto& bend : bends) {
    GridSpec bad = g;
    bend(bad);
    Grid3<float> bad_tsdf = tsdf;
    bad_tsdf.spec = bad;
    try {
      houghInstances(bad_tsdf, Grid3<Vec3f>(bad, Vec3f(1, 0, 0)));
      ADD_FAILURE() << "a grid of voxel size " << bad.voxel_size_m << " accepted";
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find("finite voxel size"), std::string::npos) << e.what();
    }
  }
}

TEST(HoughVoting, ZeroVotesDoNotCrash) {
  // Occupied voxels whose votes are all zero: no centre can be found; nothing is labelled.
  const GridSpec g = GridSpec::sceneGrid(Vec2(0, 0), 0.64, 16);
  Grid3<float> tsdf(g, 0.06f);
  for (int i = 0; i < 50; ++i) tsdf.data[2000 + i] = -0.01f;
  const InstanceSegmentation seg = houghInstances(tsdf, Grid3<Vec3f>(g, Vec3f::Zero()));
  EXPECT_EQ(seg.size(), 0);
  for (int l : seg.labels.data) EXPECT_EQ(l, -1);
}

}  // namespace
TEST(SurfaceInstances, DepthPointsNoInstanceExplainsBecomeObjects) {
  const GridSpec g = GridSpec::sceneGrid(Vec2(0.0, 0.0), 0.64, 32);
  InstanceSegmentation seg;
  seg.labels = Grid3<int>(g, -1);
  seg.voxel_counts = {0};
  // One instance: a 10 cm box of voxels about (-0.15, 0), on the table.
  for (int v = 0; v < g.voxelCount(); ++v) {
    const Vec3i c = g.unravel(v);
    const Vec3 p = g.voxelCentre(c.x(), c.y(), c.z());
    if (std::abs(p.x() + 0.15) < 0.05 && std::abs(p.y()) < 0.05 && p.z() < 0.1) {
      seg.labels.data[v] = 0;
      ++seg.voxel_counts[0];
    }
  }
  seg.centres_table = {Vec3(-0.15, 0, 0.05)};
  const auto patch = [](const Vec3& centre, double half, double z, double step) {
    Points3 pts;
    for (double x = -half; x <= half + 1e-9; x += step)
      for (double y = -half; y <= half + 1e-9; y += step)
        pts.emplace_back(centre.x() + x, centre.y() + y, z);
    return pts;
  };
  Points3 points = patch(Vec3(-0.15, 0, 0), 0.04, 0.1, 0.005);         // the box's top: explained
  const Points3 flat = patch(Vec3(0.15, 0.1, 0), 0.04, 0.016, 0.005);  // a flat item: 1.6 cm
  const Points3 low = patch(Vec3(0.0, -0.2, 0), 0.04, 0.008, 0.005);   // table noise: 8 mm
  const Points3 rim = patch(Vec3(-0.07, 0.0, 0), 0.012, 0.05, 0.003);  // beside the box
  const Points3 speck = patch(Vec3(0.2, -0.2, 0), 0.01, 0.03, 0.005);  // 25 points
  // Surfaces that do not reach down to the table: part of the box 3 voxels off, or left out.
  const Points3 wall = patch(Vec3(-0.03, 0.0, 0), 0.012, 0.06, 0.003);
  const Points3 floating = patch(Vec3(-0.25, 0.25, 0), 0.02, 0.08, 0.004);
  for (const Points3* p : {&flat, &low, &rim, &speck, &wall, &floating})
    points.insert(points.end(), p->begin(), p->end());
  SurfaceInstanceConfig config;
  EXPECT_EQ(addSurfaceInstances(points, config, &seg), 1);
  ASSERT_EQ(seg.size(), 2);
  EXPECT_LT((seg.centres_table[1].head<2>() - Vec2(0.15, 0.1)).norm(), 0.02);
  EXPECT_LT(seg.centres_table[1].z(), 0.02);  // its voxels reach down to the table
  EXPECT_EQ(seg.labels.data[nearestLabelledVoxel(seg.labels, flat.front())], 1);
  EXPECT_EQ(seg.labels.data[nearestLabelledVoxel(seg.labels, rim.back())], 0);  // attached
  EXPECT_LT(nearestLabelledVoxel(seg.labels, low.front()), 0);
  EXPECT_LT(nearestLabelledVoxel(seg.labels, speck.front()), 0);
  EXPECT_EQ(seg.labels.data[nearestLabelledVoxel(seg.labels, wall.back())], 0);
  EXPECT_LT(nearestLabelledVoxel(seg.labels, floating.front()), 0);
  int counted = 0;
  for (int l : seg.labels.data) counted += l == 1;
  EXPECT_EQ(counted, seg.voxel_counts[1]);
  // Off: nothing added; a bad field is named.
  config.enabled = false;
  EXPECT_EQ(addSurfaceInstances(points, config, &seg), 0);
  config.enabled = true;
  config.min_points = 0;
  try {
    addSurfaceInstances(points, config, &seg);
    ADD_FAILURE() << "min_points 0 accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("surface_instances.min_points"), std::string::npos);
  }
}

}  // namespace simstack

namespace simstack {

/// Depth points of an upright cylinder wall (axis at `axis`, radius `r`, heights z0..z1) on the
/// arc of angles `from`..`to` (radians), labelled `label` in `seg` (its voxels), with 1 mm noise.
static Points3 wallPoints(InstanceSegmentation* seg, int label, const Vec2& axis, double r,
                          double z0, double z1, double from, double to, std::mt19937* rng) {
  std::uniform_real_distribution<double> noise(-0.001, 0.001);
  Points3 pts;
  for (double a = from; a <= to; a += 0.02)
    for (double z = z0; z <= z1; z += 0.004) {
      const Vec3 p(axis.x() + (r + noise(*rng)) * std::cos(a),
                   axis.y() + (r + noise(*rng)) * std::sin(a), z);
      pts.push_back(p);
      const Vec3i c = seg->labels.spec.voxelIndex(p);
      if (seg->labels.spec.inside(c.x(), c.y(), c.z())) {
        int& l = seg->labels.at(c.x(), c.y(), c.z());
        if (l < 0) ++seg->voxel_counts[label];
        if (l < 0) l = label;
      }
    }
  return pts;
}

TEST(SurfaceInstances, AnOpenContainerSeenFromOutsideAndInsideIsOneObject) {
  const GridSpec g = GridSpec::sceneGrid(Vec2(0.0, 0.0), 0.64, 32);
  InstanceSegmentation seg;
  seg.labels = Grid3<int>(g, -1);
  seg.voxel_counts = {0, 0, 0, 0, 0, 0};
  seg.centres_table = {Vec3(0, -0.05, 0.06), Vec3(0, 0.05, 0.08),  Vec3(0.2, 0, 0.05),
                       Vec3(0.2, 0.1, 0.05), Vec3(-0.22, 0, 0.05), Vec3(-0.18, 0, 0.05)};
  const Vec3 camera(0.0, -1.0, 0.8);  // in front of the scene (-y), above it
  std::mt19937 rng(3);
  // A pot (radius 9 cm, 2 mm wall): its front outside, from the table up to its 12 cm rim, and
  // above the front rim the inside of its far wall.
  const Points3 outside = wallPoints(&seg, 0, Vec2(0, 0), 0.09, 0.0, 0.12, -M_PI + 0.2, -0.2, &rng);
  Points3 points = outside;
  const Points3 inside = wallPoints(&seg, 1, Vec2(0, 0), 0.088, 0.05, 0.12, 0.3, M_PI - 0.3, &rng);
  points.insert(points.end(), inside.begin(), inside.end());
  // A can beside it and a second can behind that: each shows only its front.
  for (const auto& [label, y] : {std::pair{2, 0.0}, std::pair{3, 0.1}}) {
    const Points3 can =
        wallPoints(&seg, label, Vec2(0.2, y), 0.035, 0.0, 0.1, -M_PI + 0.3, -0.3, &rng);
    points.insert(points.end(), can.begin(), can.end());
  }
  // A third can whose front the votes cut in two: its left half, the lower part of its right.
  Points3 left = wallPoints(&seg, 4, Vec2(-0.2, 0), 0.035, 0.0, 0.1, -M_PI + 0.3, -M_PI / 2, &rng);
  const Points3 right =
      wallPoints(&seg, 5, Vec2(-0.2, 0), 0.035, 0.0, 0.06, -M_PI / 2 + 0.02, -0.3, &rng);
  points.insert(points.end(), left.begin(), left.end());
  points.insert(points.end(), right.begin(), right.end());
  const RevolutionFit pot = fitCommonRevolution(outside, inside, camera.head<2>());
  ASSERT_TRUE(pot.valid);
  EXPECT_LT(pot.median_residual_m, 0.002);
  EXPECT_LT(pot.axis.norm(), 0.01);
  EXPECT_GE(pot.arc_deg, 300);
  EXPECT_GT(pot.inside_share, 0.3);

  SurfaceInstanceConfig config;
  InstanceSegmentation joined = seg;
  EXPECT_EQ(joinOpenContainers(points, camera, config, &joined), 1);
  ASSERT_EQ(joined.size(), 5);
  const int pot_label = joined.labels.data[nearestLabelledVoxel(joined.labels, points.front())];
  EXPECT_EQ(joined.labels.data[nearestLabelledVoxel(joined.labels, inside.front())], pot_label);
  EXPECT_EQ(joined.voxel_counts[pot_label], seg.voxel_counts[0] + seg.voxel_counts[1]);
  EXPECT_LT(joined.centres_table[pot_label].head<2>().norm(), 0.05);
  ASSERT_NE(seg.voxel_counts[4], seg.voxel_counts[5]);
  int counted = 0;
  for (int l : joined.labels.data) {
    EXPECT_LT(l, joined.size());
    counted += l == 4;
  }
  EXPECT_EQ(counted, seg.voxel_counts[5]);  // the last label moved down by one
  EXPECT_EQ(counted, joined.voxel_counts[4]);
  // The halves of the third can lie on one surface of revolution, seen from outside only: none of
  // their points lies beyond the axis.
  const RevolutionFit halves = fitCommonRevolution(left, right, camera.head<2>());
  ASSERT_TRUE(halves.valid);
  EXPECT_LT(halves.median_residual_m, 0.002);
  EXPECT_EQ(halves.inside_share, 0.0);
  // The front of a can and that of the can behind it lie near one circle, and the far one lies
  // beyond its axis: only their cover tells them from a container's walls, as the camera sees
  // less than half way round a convex object.
  std::vector<Points3> cans(2);
  for (const Vec3& p : points) {
    const int v = nearestLabelledVoxel(seg.labels, p);
    if (v >= 0 && (seg.labels.data[v] == 2 || seg.labels.data[v] == 3))
      cans[seg.labels.data[v] - 2].push_back(p);
  }
  const RevolutionFit two = fitCommonRevolution(cans[0], cans[1], camera.head<2>());
  ASSERT_TRUE(two.valid);
  EXPECT_GT(two.inside_share, config.container_inside_share);
  EXPECT_LT(two.arc_deg, 180);
  InstanceSegmentation other = seg;
  config.container_profile_m = 0;
  EXPECT_EQ(joinOpenContainers(points, camera, config, &other), 0);
  config.container_inside_share = 2;
  EXPECT_THROW(joinOpenContainers(points, camera, config, &other), std::invalid_argument);
}

/// Joins of the two halves of one wall (labels 0 and 1, angles from..mid and mid..to) under
/// `config`, seen from `camera`.
static int joinsOfHalves(double r, double from, double mid, double to, const Vec3& camera,
                         const SurfaceInstanceConfig& config) {
  InstanceSegmentation seg;
  seg.labels = Grid3<int>(GridSpec::sceneGrid(Vec2(0.0, 0.0), 0.64, 32), -1);
  seg.voxel_counts = {0, 0};
  seg.centres_table = {Vec3::Zero(), Vec3::Zero()};
  std::mt19937 rng(5);
  Points3 points = wallPoints(&seg, 0, Vec2(0, 0), r, 0.0, 0.12, from, mid, &rng);
  const Points3 second = wallPoints(&seg, 1, Vec2(0, 0), r, 0.0, 0.12, mid + 0.02, to, &rng);
  points.insert(points.end(), second.begin(), second.end());
  return joinOpenContainers(points, camera, config, &seg);
}

TEST(SurfaceInstances, AContainerMustGoRoundItsAxisAndBeSeenFromInside) {
  const Vec3 camera(0.0, -1.0, 0.8);  // the camera looks along +y
  SurfaceInstanceConfig config;
  // The inside of a far wall cut in two: on one surface, all beyond the axis, but 140 degrees
  // round it.
  const double far_from = 0.35, far_to = M_PI - 0.35;
  EXPECT_EQ(joinsOfHalves(0.09, far_from, M_PI / 2, far_to, camera, config), 0);
  SurfaceInstanceConfig any_arc = config;
  any_arc.container_min_arc_deg = 0;
  EXPECT_EQ(joinsOfHalves(0.09, far_from, M_PI / 2, far_to, camera, any_arc), 1);
  // A wall 250 degrees round, centred on the camera's side: the arc is there, but only its ends
  // (a seventh of it) lie beyond the axis.
  const double near_from = -M_PI / 2 - 2.18, near_to = -M_PI / 2 + 2.18;
  EXPECT_EQ(joinsOfHalves(0.09, near_from, -M_PI / 2, near_to, camera, config), 0);
  SurfaceInstanceConfig any_side = config;
  any_side.container_inside_share = 0;
  EXPECT_EQ(joinsOfHalves(0.09, near_from, -M_PI / 2, near_to, camera, any_side), 1);
}

/// A pot of radius 9 cm whose walls a finer grid parts: the outside of its near wall (label 0)
/// and the inside of its far wall (label 1), both rippled by 6.5 mm about the circle (dents, a
/// handle, a rim), so that they lie on one surface of revolution only within a few millimetres.
static InstanceSegmentation rippledPot(Points3* outside, Points3* inside) {
  InstanceSegmentation seg;
  seg.labels = Grid3<int>(GridSpec::sceneGrid(Vec2(0.0, 0.0), 0.64, 32), -1);
  seg.voxel_counts = {0, 0};
  seg.centres_table = {Vec3(0, -0.05, 0.06), Vec3(0, 0.05, 0.06)};
  const auto wall = [&](int label, double from, double to, Points3* out) {
    for (double a = from; a <= to; a += 0.02)
      for (double z = 0.0; z <= 0.12; z += 0.004) {
        const double r = 0.09 + 0.0065 * std::sin(5.0 * a);
        const Vec3 p(r * std::cos(a), r * std::sin(a), z);
        out->push_back(p);
        const Vec3i c = seg.labels.spec.voxelIndex(p);
        int& l = seg.labels.at(c.x(), c.y(), c.z());
        if (l < 0) ++seg.voxel_counts[label];
        if (l < 0) l = label;
      }
  };
  wall(0, -M_PI + 0.3, -0.3, outside);
  wall(1, 0.35, M_PI - 0.35, inside);
  return seg;
}

TEST(SurfaceInstances, AContainersPartedWallsAreJoinedWhereTheFirstPassHeldThemWhole) {
  const Vec3 camera(0.0, -1.0, 0.8);  // the camera looks along +y
  Points3 outside, inside;
  const InstanceSegmentation seg = rippledPot(&outside, &inside);
  Points3 points = outside;
  points.insert(points.end(), inside.begin(), inside.end());
  const RevolutionFit pot = fitCommonRevolution(outside, inside, camera.head<2>());
  ASSERT_TRUE(pot.valid);
  SurfaceInstanceConfig config;
  // Within the held tolerance, not within the container tolerance.
  EXPECT_GT(pot.median_residual_m, config.container_profile_m);
  EXPECT_LT(pot.median_residual_m, config.held_container_profile_m);
  EXPECT_GE(pot.arc_deg, config.container_min_arc_deg);
  InstanceSegmentation alone = seg;
  EXPECT_EQ(joinOpenContainers(points, camera, config, &alone), 0);

  // The first pass held both walls as one object: they are joined.
  InstanceSegmentation held_whole = seg;
  EXPECT_EQ(joinHeldContainers(points, camera, {points}, config, &held_whole), 1);
  EXPECT_EQ(held_whole.size(), 1);
  EXPECT_EQ(held_whole.voxel_counts[0], seg.voxel_counts[0] + seg.voxel_counts[1]);
  // As two objects, or not at all (no first pass, or its points 3 cm away), they stay apart.
  InstanceSegmentation held_apart = seg;
  EXPECT_EQ(joinHeldContainers(points, camera, {outside, inside}, config, &held_apart), 0);
  EXPECT_EQ(joinHeldContainers(points, camera, {}, config, &held_apart), 0);
  Points3 moved = points;
  for (Vec3& p : moved) p.x() += 0.03;
  EXPECT_EQ(joinHeldContainers(points, camera, {moved}, config, &held_apart), 0);
  EXPECT_EQ(held_apart.size(), 2);
  config.held_container_profile_m = 0;
  EXPECT_EQ(joinHeldContainers(points, camera, {points}, config, &held_apart), 0);
  config.held_container_profile_m = -0.001;
  EXPECT_THROW(joinHeldContainers(points, camera, {points}, config, &held_apart),
               std::invalid_argument);
}

/// A box (superquadric of exponent 10) of half extents `half` at `centre`.
static SceneObject boxAt(const Vec3& half, const Vec3& centre) {
  SuperquadricShape sq;
  sq.scale_m = half;
  sq.exponents = Vec3::Constant(10.0);
  SceneObject o;
  o.shape = ObjectShape::fromSuperquadric(sq);
  o.T_table_object.translation() = centre;
  return o;
}

/// Joins by joinOccludedPieces of `scene` seen from (0, -0.8, 0.45): its depth points (every
/// second pixel, 5 mm above the table and higher) labelled on a 32^3 grid, each point's voxel
/// taking the label `label_of` gives it (object index, table-frame point). `joined_label`
/// receives, after the joins, the labels of the points at `probes`. With `held_of` (object
/// index, point -> an earlier perception's object, or -1) the joins are joinHeldOccludedPieces',
/// held as those objects' points; `fill`, when given, edits the labels before the joins.
static int occludedJoins(const Scene& scene, const std::function<int(int, const Vec3&)>& label_of,
                         int labels, const SurfaceInstanceConfig& config,
                         const std::vector<Vec3>& probes = {},
                         std::vector<int>* joined_label = nullptr,
                         const std::function<int(int, const Vec3&)>& held_of = {},
                         const std::function<void(InstanceSegmentation*)>& fill = {}) {
  const PinholeCamera camera = scaledKinect(640, 480);
  const Transform T_table_camera = lookAt(Vec3(0.0, -0.8, 0.45), Vec3(0.0, 0.0, 0.06));
  const RenderResult view = DepthRenderer(scene).render(camera, T_table_camera);
  InstanceSegmentation seg;
  seg.labels = Grid3<int>(GridSpec::sceneGrid(Vec2(0.0, 0.0), 0.64, 32), -1);
  seg.voxel_counts.assign(labels, 0);
  seg.centres_table.assign(labels, Vec3::Zero());
  Points3 points;
  std::vector<Points3> held;
  for (int v = 0; v < camera.height; v += 2)
    for (int u = 0; u < camera.width; u += 2) {
      const float d = view.depth.at(u, v);
      const int object = view.instances.at(u, v);
      if (!(d > 0.0f) || object == 0 || object == kNoSurface) continue;
      const Vec3 p = T_table_camera * camera.backproject(u, v, d);
      if (p.z() < 0.005) continue;
      points.push_back(p);
      const int h = held_of ? held_of(object - 1, p) : -1;
      if (h >= 0) {
        held.resize(std::max(held.size(), static_cast<size_t>(h) + 1));
        held[h].push_back(p);
      }
      const int label = label_of(object - 1, p);
      const Vec3i i = seg.labels.spec.voxelIndex(p);
      if (label >= 0 && seg.labels.at(i.x(), i.y(), i.z()) < 0) {
        seg.labels.at(i.x(), i.y(), i.z()) = label;
        ++seg.voxel_counts[label];
      }
    }
  if (fill) fill(&seg);
  const int joins =
      held_of ? joinHeldOccludedPieces(points, camera, T_table_camera, 2, held, config, &seg)
              : joinOccludedPieces(points, camera, T_table_camera, 2, config, &seg);
  if (joined_label)
    for (const Vec3& p : probes) {
      const int v = nearestLabelledVoxel(seg.labels, p);
      joined_label->push_back(v >= 0 ? seg.labels.data[v] : -1);
    }
  return joins;
}

TEST(SurfaceInstances, AnObjectSeenOnBothSidesOfANearerOneIsOne) {
  // A long box behind a thin post: the post hides the box's middle, and the votes made its two
  // visible ends two instances.
  const Scene behind{{boxAt({0.12, 0.04, 0.05}, {0.0, 0.05, 0.05}),
                      boxAt({0.015, 0.015, 0.1}, {0.0, -0.06, 0.1})}};
  const auto halves = [](int object, const Vec3& p) { return object == 1 ? 2 : p.x() < 0 ? 0 : 1; };
  SurfaceInstanceConfig config;
  config.occluded_plane_m = 0.006;
  std::vector<int> after;
  EXPECT_EQ(
      occludedJoins(behind, halves, 3, config,
                    {Vec3(-0.1, 0.01, 0.05), Vec3(0.1, 0.01, 0.05), Vec3(0, -0.075, 0.1)}, &after),
      1);
  ASSERT_EQ(after.size(), 3u);
  EXPECT_GE(after[0], 0) << "a probe found no labelled voxel";
  EXPECT_EQ(after[0], after[1]);
  EXPECT_NE(after[0], after[2]);
  SurfaceInstanceConfig off = config;
  off.occluded_plane_m = 0;
  EXPECT_EQ(occludedJoins(behind, halves, 3, off), 0);
  // Two boxes of one height side by side: the table is seen between their coplanar faces.
  const Scene apart{{boxAt({0.05, 0.04, 0.05}, {-0.08, 0.05, 0.05}),
                     boxAt({0.05, 0.04, 0.05}, {0.08, 0.05, 0.05})}};
  const auto each = [](int object, const Vec3&) { return object; };
  EXPECT_EQ(occludedJoins(apart, each, 2, config), 0);
  // ... and with a post standing between them, as far back: nothing nearer hides the gap.
  Scene between = apart;
  between.objects.push_back(boxAt({0.015, 0.015, 0.1}, {0.0, 0.05, 0.1}));
  EXPECT_EQ(occludedJoins(between, each, 3, config), 0);
  // ... but with the post in front of the gap, they are one box's ends to the rule as well.
  Scene hidden = apart;
  hidden.objects.push_back(boxAt({0.04, 0.015, 0.1}, {0.0, -0.06, 0.1}));
  EXPECT_EQ(occludedJoins(hidden, each, 3, config), 1);
  // ... unless their sides along the gap do not line up: boxes of two heights, their fronts
  // on one plane.
  const Scene uneven{{boxAt({0.05, 0.04, 0.05}, {-0.08, 0.05, 0.05}),
                      boxAt({0.05, 0.04, 0.035}, {0.08, 0.05, 0.035}),
                      boxAt({0.04, 0.015, 0.1}, {0.0, -0.06, 0.1})}};
  EXPECT_EQ(occludedJoins(uneven, each, 3, config), 0);
  SurfaceInstanceConfig any_edge = config;
  any_edge.occluded_edge_m = 1.0;
  EXPECT_EQ(occludedJoins(uneven, each, 3, any_edge), 1);
  SurfaceInstanceConfig bad = config;
  bad.occluded_share = 0;
  EXPECT_THROW(occludedJoins(behind, halves, 3, bad), std::invalid_argument);
}

TEST(SurfaceInstances, AFirstPassVouchesForAnOccludedObjectsSidesAcrossTheNearerOnesVoxels) {
  // The long box behind a post of the test above, and the post's instance completed back to
  // the box, so that its voxels fill the way between the box's two visible ends.
  const Scene behind{{boxAt({0.12, 0.04, 0.05}, {0.0, 0.05, 0.05}),
                      boxAt({0.015, 0.015, 0.1}, {0.0, -0.06, 0.1})}};
  const auto halves = [](int object, const Vec3& p) { return object == 1 ? 2 : p.x() < 0 ? 0 : 1; };
  const auto postToTheBox = [](InstanceSegmentation* seg) {
    Grid3<int>& l = seg->labels;
    for (double x = -0.01; x <= 0.011; x += 0.02)  // the two voxels across the post
      for (double y = -0.07; y <= 0.03; y += 0.01)
        for (double z = 0.01; z <= 0.19; z += 0.01) {
          const Vec3i i = l.spec.voxelIndex(Vec3(x, y, z));
          int& label = l.at(i.x(), i.y(), i.z());
          if (label == 2) continue;
          if (label >= 0) --seg->voxel_counts[label];
          ++seg->voxel_counts[2];
          label = 2;
        }
  };
  SurfaceInstanceConfig config;
  config.occluded_plane_m = 0.006;
  // The way lies in the post's voxels: without a vouch, the box's ends stay two objects.
  EXPECT_EQ(occludedJoins(behind, halves, 3, config, {}, nullptr, {}, postToTheBox), 0);
  // The first pass held the box as one object and the post as another: one box.
  SurfaceInstanceConfig held = config;
  held.held_occluded_plane_m = 0.006;
  const auto firstPass = [](int object, const Vec3&) { return object; };
  std::vector<int> after;
  EXPECT_EQ(occludedJoins(behind, halves, 3, held,
                          {Vec3(-0.1, 0.01, 0.05), Vec3(0.1, 0.01, 0.05), Vec3(0, -0.075, 0.1)},
                          &after, firstPass, postToTheBox),
            1);
  ASSERT_EQ(after.size(), 3u);
  EXPECT_GE(after[0], 0) << "a probe found no labelled voxel";
  EXPECT_EQ(after[0], after[1]);
  EXPECT_NE(after[0], after[2]);
  // The first pass held the ends apart (as the votes part them), or held nothing, or the join
  // is off: no join.
  EXPECT_EQ(occludedJoins(behind, halves, 3, held, {}, nullptr, halves, postToTheBox), 0);
  const auto none = [](int, const Vec3&) { return -1; };
  EXPECT_EQ(occludedJoins(behind, halves, 3, held, {}, nullptr, none, postToTheBox), 0);
  SurfaceInstanceConfig off = held;
  off.held_occluded_plane_m = 0;
  EXPECT_EQ(occludedJoins(behind, halves, 3, off, {}, nullptr, firstPass, postToTheBox), 0);
  // The vouch does not stand for the view: two boxes side by side that the first pass held as
  // one, the table seen between them.
  const Scene side_by_side{{boxAt({0.05, 0.04, 0.05}, {-0.08, 0.05, 0.05}),
                            boxAt({0.05, 0.04, 0.05}, {0.08, 0.05, 0.05})}};
  const auto each = [](int object, const Vec3&) { return object; };
  const auto one = [](int, const Vec3&) { return 0; };
  EXPECT_EQ(occludedJoins(side_by_side, each, 2, held, {}, nullptr, one), 0);
  SurfaceInstanceConfig bad = held;
  bad.held_occluded_plane_m = -0.001;
  EXPECT_THROW(occludedJoins(behind, halves, 3, bad, {}, nullptr, firstPass),
               std::invalid_argument);
}

// Joining two instances renumbers the labels above the one dropped and weighs the centres by
// their voxels; indices out of order or range are refused.
TEST(SurfaceInstances, JoiningTwoInstancesRenumbersTheRest) {
  const GridSpec g = GridSpec::sceneGrid(Vec2(0.0, 0.0), 0.64, 32);
  InstanceSegmentation seg;
  seg.labels = Grid3<int>(g, -1);
  seg.labels.data[0] = 0;
  seg.labels.data[1] = 1;
  seg.labels.data[2] = 1;
  seg.labels.data[3] = 1;
  seg.labels.data[4] = 2;
  seg.voxel_counts = {1, 3, 1};
  seg.centres_table = {Vec3(0, 0, 0), Vec3(0.4, 0, 0), Vec3(1, 1, 1)};
  EXPECT_THROW(joinInstances(&seg, 1, 0), std::invalid_argument);
  EXPECT_THROW(joinInstances(&seg, 0, 3), std::invalid_argument);
  joinInstances(&seg, 0, 1);
  ASSERT_EQ(seg.size(), 2);
  EXPECT_EQ(seg.voxel_counts, (std::vector<int>{4, 1}));
  EXPECT_TRUE(seg.centres_table[0].isApprox(Vec3(0.3, 0, 0)));
  EXPECT_EQ(std::vector<int>(seg.labels.data.begin(), seg.labels.data.begin() + 6),
            (std::vector<int>{0, 0, 0, 0, 1, -1}));
}

}  // namespace simstack
