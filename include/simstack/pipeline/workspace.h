#pragma once
/// @file workspace.h
/// Where the pipeline looks and how it covers what it finds there.
///
/// The workspace is a box in the table frame (as pcl_ros' CropBox or octomap_server's
/// pointcloud_[min|max]_[x|y|z]): depth points outside it take no part in the pile, the grid's
/// placement, the table plane or the instances. Unbounded by default.
///
/// Tiles: the network sees a cube of fixed side (R voxels). When the occupied part of the
/// workspace is wider than one such cube, its points are split into separate groups, and each
/// group is perceived as a scene of its own: on one tile placed as training would place it, or,
/// when wider than a tile, on overlapping tiles whose predictions are blended into the group's
/// grid, where its instances are found once (objects cut by a tile border whole). The groups'
/// TSDFs and votes are then blended into one scene grid (a cube holding every group, z from the
/// table up) for the outputs. Every tile lies on the table frame's voxel lattice (its training
/// placement moved by less than a voxel), so a group's grid is copied into the scene grid
/// without resampling, and the grid stays put while the pile's centre estimate jitters by a
/// few millimetres from frame to frame. One tile is the common case.

#include <algorithm>
#include <array>
#include <functional>
#include <limits>
#include <optional>
#include <vector>

#include "simstack/geometry/depth_view.h"
#include "simstack/geometry/voxel_grid.h"
#include "simstack/types.h"

namespace simstack {

struct WorkspaceConfig {
  static constexpr double kUnbounded = std::numeric_limits<double>::infinity();
  std::array<double, 3> min_m{-kUnbounded, -kUnbounded, -kUnbounded};  ///< table frame
  std::array<double, 3> max_m{kUnbounded, kUnbounded, kUnbounded};
  int max_tiles = 9;             ///< at most this many network passes a frame
  double tile_overlap_m = 0.16;  ///< neighbouring tiles share this much (an object this wide
                                 ///< near a border is whole in one of them)

  bool bounded() const;
  bool contains(const Vec3& p_table) const;
  /// Throws std::invalid_argument naming the field (min above max, NaN, tiles < 1, overlap
  /// outside [0, side / 2) is checked by planTiles).
  void validate() const;
};

/// Table-frame points of the pile as the grid placement sees them: every `stride`-th pixel's
/// (from latticeStart) point between `min_height_m` and `max_height_m` above the table and inside
/// the workspace; `pixels` (when given) gets each point's pixel index (v * width + u).
std::vector<Vec3> pilePoints(const DepthView& view, const Transform& T_table_camera,
                             const WorkspaceConfig& workspace, double min_height_m,
                             double max_height_m, int stride = 2,
                             std::vector<int>* pixels = nullptr);

/// The x/y median of the points (each coordinate's element at size / 2). Requires at least one
/// point.
Vec2 medianXY(std::vector<Vec3> points);

/// Depth where the view's mask is 0 marked missing (nothing when the view has no mask).
void applyMask(DepthView* view);

/// Depth whose point lies outside the workspace box marked missing (nothing when unbounded).
void cropToWorkspace(DepthView* view, const Transform& T_table_camera,
                     const WorkspaceConfig& workspace);

/// A separate group of the pile's points and the tiles covering it.
struct TileGroup {
  GridSpec grid;                ///< holds the group's tiles, on their lattice; the tile when one
  std::vector<GridSpec> tiles;  ///< each the network's grid (R voxels, side extent_m)
  Vec2 lo = Vec2::Zero(), hi = Vec2::Zero();  ///< the group's points' x/y box (table frame)
};

struct TilePlan {
  GridSpec scene;                 ///< holds every group, on the table frame's voxel lattice
  std::vector<TileGroup> groups;  ///< the largest first; one group of one tile, the scene
                                  ///< itself, is the common case
  bool cropped = false;           ///< the pile needed more than max_tiles (or a wider square): its
                                  ///< largest groups (or the middle of the largest) are covered
  int tileCount() const;
  /// The group whose box is nearest the point (x/y).
  int groupOf(const Vec3& p_table) const;
};

/// Covers the pile's points (table frame) with tiles of `resolution` voxels of side `extent_m`.
/// The pile fits one tile when its x/y spread (0.5 and 99.5 percentiles, two voxels' margin on
/// each side) is at most the side: that tile is centred on `single_centre` (placed as in
/// training), moved just enough to hold the spread. `placement` maps the
/// median of a group of points to where training would centre a grid on that group.
/// Otherwise the points are split into groups (points in cells of two voxels, a whole empty cell
/// between two groups; groups whose joint spread fits one tile kept together), each perceived as a
/// scene of its own: one tile placed as in training when it fits, else the fewest tiles overlapping
/// by at least `tile_overlap_m`; the largest groups first, at most `max_tiles` tiles in all and
/// within a square of ceil(sqrt(max_tiles)) tiles' side (`cropped` says when groups were left
/// out). Flying pixels alone (groups of fewer than 10 points) take the single tile. Every tile's
/// origin is then moved (by less than a voxel) onto the table frame's voxel lattice.
TilePlan planTiles(const std::vector<Vec3>& pile_points, const Vec2& single_centre,
                   const std::function<Vec2(const Vec2&)>& placement, double extent_m,
                   int resolution, const WorkspaceConfig& workspace);

/// How much a tile counts at a table-frame point: the point's distance (in voxels) from the
/// tile's nearest side face, where its view of the scene is cut (plus 1e-3, so that a point on
/// the face still counts); 0 outside the tile.
double tileWeight(const GridSpec& tile, const Vec3& p_table);
/// A group's weight at a point: its tile holding the point farthest in (0 outside every tile of
/// the group; a group's grid is a cube its tiles need not fill).
double groupWeight(const TileGroup& group, const Vec3& p_table);

/// The grids blended onto `scene`: each voxel the mean of the grids (trilinear) weighted by
/// `weight(k, p)` for grid k at the voxel's centre p; voxels no grid weighs get `outside`.
/// A grid on the scene's voxel lattice is copied exactly.
template <typename T, typename Weight>
Grid3<T> blendGrids(const GridSpec& scene, const std::vector<Grid3<T>>& grids, Weight&& weight,
                    const T& outside) {
  Grid3<T> out(scene, outside);
  for (int i = 0; i < scene.voxelCount(); ++i) {
    const Vec3i v = scene.unravel(i);
    const Vec3 p = scene.voxelCentre(v.x(), v.y(), v.z());
    T sum = outside * 0.0f;
    double total = 0.0;
    for (size_t k = 0; k < grids.size(); ++k) {
      const double w = weight(k, p);
      if (w <= 0.0) continue;
      sum = sum + grids[k].sampleTrilinear(p) * static_cast<float>(w);
      total += w;
    }
    if (total > 0.0) out.data[i] = sum * static_cast<float>(1.0 / total);
  }
  return out;
}

/// Tile predictions blended onto `scene`, each weighted by tileWeight; one tile that is the
/// scene is returned as it is.
template <typename T>
Grid3<T> blendTiles(const GridSpec& scene, const std::vector<Grid3<T>>& tiles, const T& outside) {
  if (tiles.size() == 1 && tiles.front().spec == scene) return tiles.front();
  return blendGrids(
      scene, tiles, [&](size_t k, const Vec3& p) { return tileWeight(tiles[k].spec, p); }, outside);
}

}  // namespace simstack
