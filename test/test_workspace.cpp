// Workcell scenes: the workspace box and mask, the table plane among other planes, and tiles
// for piles wider than one grid.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <random>

#include "simstack/offline/dataset/ground_truth.h"
#include "simstack/offline/eval/occupancy.h"
#include "simstack/offline/piles/pile_generator.h"
#include "simstack/pipeline/scene_perception.h"
#include "simstack/render/depth_renderer.h"
#include "test_scenes.h"

namespace simstack {
namespace {

const std::string kModel = std::string(SIMSTACK_SOURCE_DIR) + "/models/simstack_r32.pt";

/// Training's placement for the synthetic clusters below: their centre is their median.
const std::function<Vec2(const Vec2&)> kCentroid = [](const Vec2& median) { return median; };

std::vector<Vec3> cluster(const Vec2& centre, double half_width) {
  std::vector<Vec3> out;
  for (int i = -10; i <= 10; ++i)
    for (int j = -10; j <= 10; ++j)
      out.emplace_back(centre.x() + half_width * i / 10.0, centre.y() + half_width * j / 10.0,
                       0.05);
  return out;
}

TEST(PlanTiles, ACompactPileTakesOneTileWhereTrainingPlacesIt) {
  const Vec2 centre(0.1, -0.2);
  const TilePlan plan =
      planTiles(cluster(centre, 0.15), centre, kCentroid, 0.64, 32, WorkspaceConfig());
  ASSERT_EQ(plan.tileCount(), 1);
  EXPECT_EQ(plan.scene, GridSpec::sceneGrid(centre, 0.64, 32));
  EXPECT_EQ(plan.groups.front().tiles.front(), plan.scene);
  EXPECT_EQ(plan.groups.front().grid, plan.scene);
  EXPECT_FALSE(plan.cropped);
  // A placement that would cut the pile is moved just enough to hold it.
  const TilePlan moved = planTiles(cluster(centre, 0.2), centre + Vec2(0.2, 0.0), kCentroid, 0.64,
                                   32, WorkspaceConfig());
  ASSERT_EQ(moved.tileCount(), 1);
  EXPECT_LE(moved.scene.origin_table.x(), centre.x() - 0.2 - 0.04 + 1e-9);
}

/// True when every point lies in some tile, 1.5 voxels from its x/y sides, and every tile in
/// the scene grid.
bool covered(const TilePlan& plan, const std::vector<Vec3>& points) {
  std::vector<GridSpec> tiles;
  for (const TileGroup& g : plan.groups) tiles.insert(tiles.end(), g.tiles.begin(), g.tiles.end());
  for (const Vec3& p : points) {
    bool held = false;
    for (const GridSpec& t : tiles) {
      const Vec3 c = t.continuousIndex(p) + Vec3::Constant(0.5);
      held |= c.x() >= 1.5 && c.x() <= t.resolution - 1.5 && c.y() >= 1.5 &&
              c.y() <= t.resolution - 1.5;
    }
    if (!held) return false;
  }
  for (const GridSpec& t : tiles)
    for (const Vec3& corner :
         std::array<Vec3, 2>{t.origin_table, Vec3(t.origin_table + Vec3::Constant(t.extent_m()))}) {
      const Vec3 c = plan.scene.continuousIndex(corner) + Vec3::Constant(0.5);
      if ((c.array() < -1e-6).any() || (c.array() > plan.scene.resolution + 1e-6).any())
        return false;
    }
  return true;
}

TEST(PlanTiles, SeparatePilesTakeOneTileEachCentredOnThem) {
  std::vector<Vec3> points = cluster(Vec2(-0.45, 0.0), 0.15);
  for (const Vec3& p : cluster(Vec2(0.45, 0.1), 0.15)) points.push_back(p);
  const TilePlan plan = planTiles(points, Vec2::Zero(), kCentroid, 0.64, 32, WorkspaceConfig());
  ASSERT_EQ(plan.groups.size(), 2u);
  ASSERT_EQ(plan.tileCount(), 2);
  EXPECT_FALSE(plan.cropped);
  EXPECT_NEAR(plan.scene.voxel_size_m, 0.02, 1e-12);
  EXPECT_TRUE(covered(plan, points));
  std::vector<Vec2> centres;
  for (const TileGroup& g : plan.groups) {
    const GridSpec& t = g.tiles.front();
    EXPECT_EQ(g.grid, t);
    EXPECT_EQ(t.resolution, 32);
    EXPECT_NEAR(t.extent_m(), 0.64, 1e-9);
    centres.push_back((t.origin_table + Vec3::Constant(0.32)).head<2>());
  }
  std::sort(centres.begin(), centres.end(), [](auto& a, auto& b) { return a.x() < b.x(); });
  // Each where training would place it (here: on the group's median), moved onto the table
  // frame's voxel lattice (by up to half a voxel along each axis).
  EXPECT_LE((centres[0] - Vec2(-0.45, 0.0)).cwiseAbs().maxCoeff(), 0.01 + 1e-9);
  EXPECT_LE((centres[1] - Vec2(0.45, 0.1)).cwiseAbs().maxCoeff(), 0.01 + 1e-9);
  for (const TileGroup& g : plan.groups) {
    const Vec2 o = g.grid.origin_table.head<2>() / 0.02;
    EXPECT_LT((o - o.array().round().matrix()).norm(), 1e-6);
  }
}

TEST(PlanTiles, AWidePileIsCoveredByOverlappingTiles) {
  std::vector<Vec3> points;
  for (int i = 0; i <= 100; ++i)
    for (int j = 0; j <= 30; ++j) points.emplace_back(-0.5 + 0.01 * i, 0.2 + 0.01 * j, 0.05);
  WorkspaceConfig ws;
  const TilePlan plan = planTiles(points, Vec2::Zero(), kCentroid, 0.64, 32, ws);
  ASSERT_EQ(plan.groups.size(), 1u);
  ASSERT_GE(plan.tileCount(), 2);
  EXPECT_TRUE(covered(plan, points));
  std::vector<double> xs;
  for (const GridSpec& t : plan.groups.front().tiles) xs.push_back(t.origin_table.x());
  std::sort(xs.begin(), xs.end());
  for (size_t k = 1; k < xs.size(); ++k)
    EXPECT_GE(0.64 - (xs[k] - xs[k - 1]), ws.tile_overlap_m - 1e-9);
  // Capped at max_tiles: the middle is covered and the plan says so.
  ws.max_tiles = 1;
  const TilePlan capped = planTiles(points, Vec2::Zero(), kCentroid, 0.64, 32, ws);
  EXPECT_EQ(capped.tileCount(), 1);
  EXPECT_TRUE(capped.cropped);
}

TEST(PlanTiles, ARowLongerThanTheScenesSquareIsCroppedToIt) {
  // 5 m of objects in a row, 0.3 m wide: the tiles nearest its middle within the square of
  // ceil(sqrt(max_tiles)) tiles, not a grid as long as the row (a cube of its length).
  std::vector<Vec3> points;
  for (int i = 0; i <= 500; ++i)
    for (int j = 0; j <= 30; ++j) points.emplace_back(-2.5 + 0.01 * i, 0.01 * j, 0.05);
  const WorkspaceConfig ws;
  const TilePlan plan = planTiles(points, Vec2::Zero(), kCentroid, 0.64, 32, ws);
  EXPECT_TRUE(plan.cropped);
  ASSERT_EQ(plan.groups.size(), 1u);
  EXPECT_LE(plan.tileCount(), ws.max_tiles);
  EXPECT_LE(plan.scene.resolution, 3 * 32);
  EXPECT_LE(plan.groups.front().grid.resolution, 3 * 32);
  // The middle of the row is covered.
  EXPECT_TRUE(
      covered(plan, {Vec3(0.0, 0.15, 0.05), Vec3(0.6, 0.15, 0.05), Vec3(-0.6, 0.15, 0.05)}));
}

TEST(PlanTiles, BlendingKeepsAgreeingTilesAndFillsTheRest) {
  std::vector<Vec3> points = cluster(Vec2(-0.45, 0.0), 0.15);
  for (const Vec3& p : cluster(Vec2(0.45, 0.0), 0.15)) points.push_back(p);
  const auto shifted = [](const Vec2& median) -> Vec2 { return median + Vec2(0.007, -0.003); };
  const TilePlan plan = planTiles(points, Vec2::Zero(), shifted, 0.64, 32, WorkspaceConfig());
  ASSERT_EQ(plan.groups.size(), 2u);
  // A tile on the scene's lattice is copied exactly; a constant field stays constant.
  std::vector<GridSpec> specs = {plan.groups[0].grid, plan.groups[1].grid};
  std::vector<Grid3<float>> tiles;
  for (const GridSpec& t : specs) {
    tiles.emplace_back(t, 0.0f);
    for (int i = 0; i < t.voxelCount(); ++i) tiles.back().data[i] = -0.5f + 1e-4f * (i % 7);
  }
  const Grid3<float> blended = blendTiles(plan.scene, tiles, 1.0f);
  int inside = 0, outside = 0;
  for (int i = 0; i < plan.scene.voxelCount(); ++i) {
    const Vec3i v = plan.scene.unravel(i);
    const Vec3 p = plan.scene.voxelCentre(v.x(), v.y(), v.z());
    if (specs[0].containsPoint(p)) {
      const Vec3i j = specs[0].voxelIndex(p);
      ASSERT_NEAR(blended.data[i], tiles[0].at(j.x(), j.y(), j.z()), 1e-5);
      ++inside;
    } else if (!specs[1].containsPoint(p)) {
      ASSERT_EQ(blended.data[i], 1.0f);
      ++outside;
    } else {
      ASSERT_NEAR(blended.data[i], -0.5f, 1e-3);
    }
  }
  EXPECT_GT(inside, 0);
  EXPECT_GT(outside, 0);  // between the piles and above the tiles
}

TEST(Workspace, ConfigReadsBoundsAndRejectsAnEmptyBox) {
  const std::string path = test::tempPath("simstack_workspace.yaml");
  std::ofstream(path) << "workspace:\n  min_m: [-0.3, -0.25, -.inf]\n  max_m: [0.3, 0.25, 0.4]\n"
                         "  max_tiles: 4\n";
  const PerceptionConfig c = loadPerceptionYaml(path);
  EXPECT_TRUE(c.workspace.bounded());
  EXPECT_EQ(c.workspace.max_tiles, 4);
  EXPECT_TRUE(c.workspace.contains(Vec3(0.0, 0.0, -5.0)));
  EXPECT_FALSE(c.workspace.contains(Vec3(0.31, 0.0, 0.1)));
  EXPECT_FALSE(c.workspace.contains(Vec3(0.0, 0.0, 0.5)));
  // Written and read again, the same box (infinite bounds included).
  std::ofstream(path) << perceptionYaml(c);
  EXPECT_EQ(perceptionYaml(loadPerceptionYaml(path)), perceptionYaml(c));
  EXPECT_FALSE(PerceptionConfig().workspace.bounded());
  WorkspaceConfig empty;
  empty.min_m[0] = 0.2;
  empty.max_m[0] = 0.1;
  try {
    empty.validate();
    ADD_FAILURE() << "an empty box must be an error";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("min_m.x"), std::string::npos) << e.what();
  }
  std::filesystem::remove(path);
}

/// A generated pile moved by `shift` in x/y.
std::vector<SceneObject> pileAt(uint64_t seed, const Vec2& shift) {
  std::vector<SceneObject> out = PileGenerator(PileConfig()).generate(seed).scene.objects;
  for (SceneObject& o : out) {
    const Vec3 c = o.T_table_object.translation();
    o.T_table_object.translation() = Vec3(c.x() + shift.x(), c.y() + shift.y(), c.z());
  }
  return out;
}

SceneObject box(const Vec3& centre, const Vec3& half_size) {
  SuperquadricShape sq;
  sq.scale_m = half_size;
  sq.exponents = Vec3::Constant(20.0);
  sq.T_table_object.translation() = centre;
  SceneObject o;
  o.shape = ObjectShape::fromSuperquadric(sq);
  o.T_table_object = sq.T_table_object;
  return o;
}

DepthView render(const Scene& scene, const PinholeCamera& camera, const Transform& pose,
                 double table_half_size_m = 1.5) {
  RenderConfig rc;
  rc.table_half_size_m = table_half_size_m;
  return DepthView{DepthRenderer(scene, rc).render(camera, pose).depth, camera, pose};
}

/// Occupancy IoU of hypothesis 0 against the truth at random points around `truth`'s objects
/// (their bounding box grown by 5 cm, from the table up): free of the grids' voxel lattices,
/// so that estimates on different grids compare. Points outside the estimate's grid are free.
double pileIou(const SceneEstimate& est, const Scene& truth) {
  Vec3 lo = Vec3::Constant(1e9), hi = Vec3::Constant(-1e9);
  for (const SceneObject& o : truth.objects) {
    const SuperquadricShape sq = o.superquadricTable();
    lo = lo.cwiseMin(sq.centroid() - Vec3::Constant(sq.scale_m.maxCoeff() + 0.05));
    hi = hi.cwiseMax(sq.centroid() + Vec3::Constant(sq.scale_m.maxCoeff() + 0.05));
  }
  lo.z() = 0.0;
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  long inter = 0, uni = 0;
  for (int k = 0; k < 200000; ++k) {
    const Vec3 p = lo + (hi - lo).cwiseProduct(Vec3(u(rng), u(rng), u(rng)));
    bool y = false;
    for (const SceneObject& o : truth.objects) y = y || o.contains(p);
    const bool q = est.grid.containsPoint(p) && est.hypotheses[0].tsdf_m.sampleTrilinear(p) <= 0;
    inter += y && q;
    uni += y || q;
  }
  return uni > 0 ? static_cast<double>(inter) / uni : 0.0;
}

TEST(Tiles, TwoPilesFarApartAreEachPerceivedAsAlone) {
  ASSERT_TRUE(std::filesystem::exists(kModel)) << kModel << " is missing (the models are in git)";
  PerceptionConfig config;
  config.model_path = kModel;
  // One grid: whether a frame is perceived again in a finer one is decided over the whole
  // frame (the median, or the smallest object, of both piles), so a pile alone and the two
  // together could be perceived in grids of different sides, which is not what this compares.
  config.grid.object_voxels = 0.0;
  const ScenePerception perception(config);
  const PinholeCamera camera = test::wideCamera();
  const Transform pose = lookAt(Vec3(0.0, -0.55, 0.95), Vec3(0.0, 0.0, 0.0));
  double joint_iou = 0.0, alone_iou = 0.0;
  for (uint64_t seed = 21; seed < 31; ++seed) {
    Scene left, right, both;
    left.objects = pileAt(seed, Vec2(-0.45, 0.0));
    right.objects = pileAt(seed + 100, Vec2(0.45, 0.0));
    both.objects = left.objects;
    both.objects.insert(both.objects.end(), right.objects.begin(), right.objects.end());
    const SceneEstimate est = perception.perceive(render(both, camera, pose));
    EXPECT_GE(est.tiles, 2) << "seed " << seed;
    EXPECT_GE(est.grid.extent_m(), 1.0);
    // Every object found once: each pile's instances are those it has when seen alone (same
    // camera, one tile), none lost or doubled at a tile's border. Compared by their Hough
    // centres, within a voxel: the network's output varies in its last bits with where its
    // buffers lie in memory (oneDNN), which can move a centre by a fraction of a voxel.
    std::vector<int> taken(est.instances().size(), 0);
    for (const Scene* pile : {&left, &right}) {
      const SceneEstimate alone = perception.perceive(render(*pile, camera, pose));
      EXPECT_EQ(alone.tiles, 1);
      ASSERT_FALSE(alone.instances().empty()) << "seed " << seed;
      for (const InstanceEstimate& a : alone.instances()) {
        int best = -1;
        double best_d = 1e9;
        for (size_t k = 0; k < est.instances().size(); ++k) {
          const double d = (est.instances()[k].vote_centre - a.vote_centre).norm();
          if (d < best_d) best_d = d, best = static_cast<int>(k);
        }
        EXPECT_LT(best_d, est.grid.voxel_size_m) << "seed " << seed;
        if (best >= 0) ++taken[best];
      }
      // The scene grid's TSDF is the pile's own: both groups lie on the table frame's voxel
      // lattice, so neither is resampled.
      const Vec3 shift = (alone.grid.origin_table - est.grid.origin_table) / est.grid.voxel_size_m;
      EXPECT_LT((shift - shift.array().round().matrix()).norm(), 1e-6) << "seed " << seed;
      const double j = pileIou(est, *pile), a = pileIou(alone, *pile);
      EXPECT_GE(j, a - 1e-3) << "seed " << seed;  // the same last-bit variation
      EXPECT_GT(a, 0.4) << "seed " << seed;       // a pile, not an empty or wrong scene
      joint_iou += j;
      alone_iou += a;
    }
    for (int t : taken) EXPECT_EQ(t, 1) << "seed " << seed;
  }
  std::cout << "mean IoU of the 20 piles: " << joint_iou / 20 << " joint, " << alone_iou / 20
            << " alone\n";
}

/// The frame estimateTablePlane gives for the true table: origin below the camera, x along
/// the camera's x axis on the plane.
Transform ransacConvention(const Transform& T_table_camera) {
  const Vec3 n = T_table_camera.linear().transpose() * Vec3::UnitZ();  // camera frame
  const double d = T_table_camera.translation().z();
  Vec3 x = Vec3::UnitX() - Vec3::UnitX().dot(n) * n;
  x.normalize();
  Transform T_camera_table = Transform::Identity();
  T_camera_table.linear() << x, n.cross(x), n;
  T_camera_table.translation() = -d * n;
  return T_camera_table.inverse();
}

TEST(Workspace, ARobotBaseAndAWallOutsideItAreNeitherTableNorObjects) {
  ASSERT_TRUE(std::filesystem::exists(kModel)) << kModel << " is missing (the models are in git)";
  Scene scene;
  scene.objects = pileAt(31, Vec2::Zero());
  const size_t pile = scene.objects.size();
  // A robot's base close to the camera, beside the workspace, whose top holds more pixels than
  // the (small) table, and a wall behind the table.
  scene.objects.push_back(box(Vec3(0.75, 0.0, 0.15), Vec3(0.4, 0.6, 0.15)));
  scene.objects.push_back(box(Vec3(0.0, 0.75, 0.3), Vec3(0.9, 0.02, 0.3)));
  const PinholeCamera camera = test::wideCamera();
  const Transform pose = lookAt(Vec3(0.3, -0.6, 1.0), Vec3(0.3, 0.0, 0.0));
  const DepthView view = render(scene, camera, pose, 0.6);
  PerceptionConfig config;
  config.model_path = kModel;
  config.workspace.min_m = {-0.3, -0.3, -0.05};
  config.workspace.max_m = {0.3, 0.3, 0.5};
  {
    const ScenePerception perception(config);
    const SceneEstimate est = perception.perceive(view);
    EXPECT_EQ(est.tiles, 1);
    EXPECT_GE(est.instances().size(), pile - 1);
    EXPECT_LE(est.instances().size(), pile + 1);
    for (const InstanceEstimate& e : est.instances())
      EXPECT_TRUE(config.workspace.contains(e.vote_centre)) << e.vote_centre.transpose();
    // Without the workspace, the base and the wall widen the scene beyond one tile.
    PerceptionConfig open = config;
    open.workspace = WorkspaceConfig();
    const SceneEstimate all = ScenePerception(open).perceive(view);
    EXPECT_GT(all.tiles, 1);
  }
  // No pose: the table plane from the points in the workspace (given in the frame RANSAC
  // defines, where the truth puts the pile's box), right although the base's top is nearer.
  const Transform T_ransac_table = ransacConvention(pose) * pose.inverse();
  WorkspaceConfig ws;
  const Vec3 lo = T_ransac_table * Vec3(-0.3, -0.3, 0.0), hi = T_ransac_table * Vec3(0.3, 0.3, 0.0);
  for (int a = 0; a < 2; ++a) {
    ws.min_m[a] = std::min(lo[a], hi[a]);
    ws.max_m[a] = std::max(lo[a], hi[a]);
  }
  ws.min_m[2] = -0.05;
  ws.max_m[2] = 0.5;
  const TablePlane plane = estimateTablePlane(view.depth, camera, TablePlaneConfig(), ws);
  const Vec3 z_true = pose.linear().transpose() * Vec3::UnitZ();
  const Vec3 z_est = plane.T_table_camera.linear().transpose() * Vec3::UnitZ();
  EXPECT_GT(z_true.dot(z_est), std::cos(M_PI / 180.0));
  EXPECT_NEAR(plane.T_table_camera.translation().z(), pose.translation().z(), 0.005);
  // The largest plane alone is the base's top, 0.3 m above the table.
  const TablePlane largest = estimateTablePlane(view.depth, camera);
  EXPECT_GT(std::abs(largest.T_table_camera.translation().z() - pose.translation().z()), 0.2);
}

}  // namespace
}  // namespace simstack

namespace simstack {
namespace {

TEST(Tiles, ARowWiderThanATileIsFoundWholeAcrossTileBorders) {
  ASSERT_TRUE(std::filesystem::exists(kModel)) << kModel << " is missing (the models are in git)";
  PerceptionConfig config;
  config.model_path = kModel;
  const ScenePerception perception(config);
  // Seven boxes in a row 1.1 m long, 2 cm apart: one group, covered by overlapping tiles.
  Scene row;
  for (int k = -3; k <= 3; ++k)
    row.objects.push_back(box(Vec3(0.16 * k, 0.0, 0.05), Vec3(0.07, 0.07, 0.05)));
  const Transform pose = lookAt(Vec3(0.0, -0.7, 1.0), Vec3(0.0, 0.0, 0.0));
  const SceneEstimate est = perception.perceive(render(row, test::wideCamera(), pose));
  EXPECT_GE(est.tiles, 2);
  EXPECT_EQ(est.instances().size(), row.objects.size());
  for (const SceneObject& o : row.objects) {
    double best = 1e9;
    for (const InstanceEstimate& e : est.instances())
      best = std::min(best, (e.vote_centre - o.T_table_object.translation()).norm());
    EXPECT_LT(best, 0.04) << o.T_table_object.translation().transpose();
  }
  const double iou = pileIou(est, row);
  EXPECT_GT(iou, 0.6);
  std::cout << "row of " << row.objects.size() << " boxes: " << est.tiles << " tiles, "
            << est.instances().size() << " instances, IoU " << iou << "\n";
}

/// `g` inside a larger grid on the same lattice, `offset` voxels in, `fill` elsewhere.
template <typename T>
Grid3<T> embedded(const Grid3<T>& g, int n, const Vec3i& offset, const T& fill) {
  GridSpec s = g.spec;
  s.resolution = n;
  s.origin_table -= s.voxel_size_m * offset.cast<double>();
  Grid3<T> out(s, fill);
  const int r = g.spec.resolution;
  for (int z = 0; z < r; ++z)
    for (int y = 0; y < r; ++y)
      for (int x = 0; x < r; ++x)
        out.at(x + offset.x(), y + offset.y(), z + offset.z()) = g.at(x, y, z);
  return out;
}

TEST(Tiles, DecompositionDoesNotDependOnTheGridAroundThePile) {
  ASSERT_TRUE(std::filesystem::exists(kModel)) << kModel << " is missing (the models are in git)";
  PerceptionConfig config;
  config.model_path = kModel;
  config.segments.enabled = false;
  // One grid, the one embedded; no fits joined for overlapping (the fits, made on points drawn
  // per instance, are not what this compares).
  config.grid.object_voxels = 0.0;
  config.surface_instances.fit_overlap_share = 0.0;
  const ScenePerception perception(config);
  const PinholeCamera camera = test::wideCamera();
  const Transform pose = lookAt(Vec3(0.0, -0.55, 0.95), Vec3(0.0, 0.0, 0.0));
  for (uint64_t seed = 121; seed < 131; ++seed) {
    Scene pile;
    pile.objects = pileAt(seed, Vec2::Zero());
    const SceneEstimate est = perception.perceive(render(pile, camera, pose));
    SceneHypothesis big;
    big.tsdf_m = embedded(est.hypotheses[0].tsdf_m, 70, Vec3i(20, 7, 0), 0.06f);
    big.votes = embedded(est.hypotheses[0].votes, 70, Vec3i(20, 7, 0), Vec3f(Vec3f::Zero()));
    decompose(&big, config);
    std::cout << "seed " << seed << ": alone " << est.instances().size() << ", embedded "
              << big.instances.size() << "\n";
    EXPECT_GT(est.instances().size(), 0u) << "seed " << seed;
    EXPECT_EQ(big.instances.size(), est.instances().size()) << "seed " << seed;
  }
}

TEST(Tiles, AnObjectTheTilesCutIsTruncated) {
  ASSERT_TRUE(std::filesystem::exists(kModel)) << kModel << " is missing (the models are in git)";
  // A box 1.1 m long, wholly in view: with one tile allowed the pile is cut at the tile's side,
  // and the object's far end is a guess; with the tiles it needs it is whole.
  Scene scene;
  scene.objects.push_back(box(Vec3(0.0, 0.0, 0.04), Vec3(0.55, 0.05, 0.04)));
  const DepthView view =
      render(scene, test::wideCamera(), lookAt(Vec3(0.0, -0.7, 1.0), Vec3(0.0, 0.0, 0.0)));
  PerceptionConfig config;
  config.model_path = kModel;
  for (const int max_tiles : {9, 1}) {
    config.workspace.max_tiles = max_tiles;
    const SceneEstimate est = ScenePerception(config).perceive(view);
    EXPECT_EQ(est.tiles_cropped, max_tiles == 1);
    ASSERT_FALSE(est.instances().empty()) << max_tiles << " tiles";
    bool truncated = false;
    for (const InstanceEstimate& e : est.instances()) truncated = truncated || e.truncated;
    EXPECT_EQ(truncated, max_tiles == 1) << "max_tiles " << max_tiles;
  }
}

TEST(Workspace, DepthInStepWithTheSamplingStridePlacesThePileAsTheWholeImage) {
  ASSERT_TRUE(std::filesystem::exists(kModel)) << kModel << " is missing (the models are in git)";
  // A depth image on every other row and column of its frame (registered into a frame twice
  // its size): the pile is found, on either lattice, where the whole image places it.
  Scene scene;
  scene.objects.push_back(box(Vec3(0.05, 0.02, 0.05), Vec3(0.07, 0.05, 0.05)));
  const DepthView full = render(scene, test::centredCamera(640, 480, 525.0),
                                lookAt(Vec3(0.3, -0.4, 0.7), Vec3(0.0, 0.0, 0.0)));
  PerceptionConfig config;
  config.model_path = kModel;
  const ScenePerception perception(config);
  const SceneEstimate whole = perception.perceive(full);
  ASSERT_EQ(whole.instances().size(), 1u);
  for (const int phase : {0, 1}) {
    DepthView sparse = full;
    for (int v = 0; v < full.depth.height; ++v)
      for (int u = 0; u < full.depth.width; ++u)
        if (u % 2 != phase || v % 2 != phase) sparse.depth.at(u, v) = 0.0f;
    EXPECT_FALSE(pilePoints(sparse, *full.T_table_camera, WorkspaceConfig(), 0.01, 1.0).empty());
    const SceneEstimate est = perception.perceive(sparse);
    EXPECT_LT((est.grid.origin_table - whole.grid.origin_table).norm(), 0.03) << "phase " << phase;
    EXPECT_EQ(est.instances().size(), 1u) << "phase " << phase;
  }
}

}  // namespace
}  // namespace simstack
