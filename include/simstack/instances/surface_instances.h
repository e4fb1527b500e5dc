#pragma once
/// @file surface_instances.h
/// Objects the network left out, found on the measured surface: depth points clearly above the
/// table that no instance's voxels explain are clustered (PCL's Euclidean clustering), and each
/// cluster becomes an instance of its own (its voxels and those below them down to the table),
/// or part of the instance it lies against. Flat items lying on the table (a phone, a book) and
/// small ones the network's 2 cm voxels do not resolve are found so.

#include <vector>

#include "simstack/geometry/pinhole_camera.h"
#include "simstack/geometry/voxel_grid.h"
#include "simstack/instances/hough_voting.h"

namespace simstack {

struct SurfaceInstanceConfig {
  bool enabled = true;
  /// A cluster is an object when its highest points (its 90th percentile) rise this high above
  /// the table: above the table's noise, which the pile's threshold already keeps out.
  double min_height_m = 0.012;
  /// An object stands on the table: a cluster whose lowest points (its 10th percentile) are
  /// higher than this is part of the nearest instance within four voxels, else left out.
  double max_base_height_m = 0.03;
  double cluster_tolerance_m = 0.01;  ///< neighbour distance within a cluster
  int min_points = 40;                ///< smaller clusters are noise (points as given)
  /// A cluster with this share of its points lying against one instance is part of that
  /// instance (a rim or wall its voxels missed), not an object of its own: points on a convex
  /// patch (surface_segments.h) whose explained points are mostly the instance's, or, without
  /// patches, within two voxels of its voxels.
  double attach_share = 0.1;
  /// Two instances are one open container (a pot's front wall and the inside of its far wall, a
  /// bowl's outside and inside) when their depth points, over the heights both reach, lie on
  /// one upright surface of revolution within this median distance (m), surround its axis
  /// over `container_min_arc_deg` and are in part seen from inside (`container_inside_share`):
  /// no convex object shows the camera its far side. 0 = off.
  double container_profile_m = 0.003;
  double container_min_arc_deg = 240;   ///< ... their points' angular cover about the axis
  double container_inside_share = 0.2;  ///< ... their share beyond the axis, seen from the camera
  /// In a second, finer pass (grid: object_voxels): two instances the first pass held as one
  /// object are one open container within this median distance (m), by the same arc and
  /// inside share. Objects that look small part in the finer grid, and so may a container's
  /// walls; the first pass vouches for the pair. 0 = off.
  double held_container_profile_m = 0.006;
  /// Two instances are the two sides of one object seen past a nearer one (a box behind a
  /// bottle) when their largest planar faces (RANSAC inliers within this distance, m) lie on
  /// one plane (70 % of each face's points on the plane through both, normals within 20
  /// degrees) and, between their nearest points, 1-30 cm apart, the depth is nearer to the
  /// camera than that plane by `occluded_margin_m` for `occluded_share` of the way where there
  /// is depth, at most 40 % of it missing (the camera's shadow beside the hiding surface).
  /// Where the plane goes on, or the table or something behind is seen through the gap, they
  /// are two objects; so too when the way lies mostly (60 %) in a third instance's voxels.
  /// 0 = off (the default: with `fc`, which completes such objects whole itself, it joined
  /// only separate objects; 0.006 with networks that part small neighbours).
  double occluded_plane_m = 0.0;
  double occluded_margin_m = 0.015;  ///< ... how much nearer the hiding surface is
  double occluded_share = 0.8;       ///< ... share of the gap it hides
  /// ... and the faces' sides along the gap line up within this (m): across the gap, in the
  /// plane, their points' 5th and 95th percentiles differ by at most this much.
  double occluded_edge_m = 0.015;
  /// In a second, finer pass: two instances the first pass held as one object are its sides
  /// seen past a nearer one by the `occluded_*` tests with faces found within this distance
  /// (m), even where the way between them lies in a third instance's voxels (the first pass
  /// saw the object whole around it). 0 = off.
  double held_occluded_plane_m = 0.006;
  /// Two instances are one object when their own superquadrics (each fitted alone, before the
  /// joint refinement pushes them apart) overlap by this share of the smaller one's volume: two
  /// solid objects cannot. The joined instance is fitted again on both point sets. 0 = off.
  double fit_overlap_share = 0.8;
  void validate() const;  ///< std::invalid_argument naming the field
};

/// PCL's Euclidean clustering of `points`: clusters of at least `min_points` whose points
/// lie within `tolerance_m` of another of theirs, each as indices into `points`.
std::vector<std::vector<int>> euclideanClusters(const Points3& points, double tolerance_m,
                                                int min_points);

/// Adds to `seg` (labels on its grid, centres and voxel counts) the clusters of `points_table`
/// (table frame; depth points above the pile's threshold) that no labelled voxel explains
/// (nearestLabelledVoxel finds none): an attached cluster's unlabelled voxels take its
/// instance's label, any other its own label, appended after the existing ones. `patch`, when
/// given, holds each point's convex patch (SurfaceSegments::patch, -1 none). Returns the number
/// of instances added. std::invalid_argument for a bad config or patch count.
int addSurfaceInstances(const Points3& points_table, const SurfaceInstanceConfig& config,
                        InstanceSegmentation* seg, const std::vector<int>* patch = nullptr);

/// How well two point sets (table frame) lie on one upright surface of revolution: the axis
/// and one radius per `bin_m` of height fitted by linear least squares (x^2 + y^2 = 2 c . p +
/// k_bin) to the points of the heights both sets reach, at least three points each.
struct RevolutionFit {
  bool valid = false;            ///< enough shared heights, a real radius in each
  Vec2 axis = Vec2::Zero();      ///< the axis' position on the table
  double median_residual_m = 0;  ///< median | |p - axis| - radius(height) |
  double arc_deg = 0;  ///< angular cover of the fitted points about the axis (10-degree sectors)
  /// Share beyond the axis from `camera_xy` by more than a fifth of their radius: seen from inside.
  double inside_share = 0;
  double max_radius_m = 0;
  int points = 0;  ///< points fitted (on the shared heights)
};
RevolutionFit fitCommonRevolution(const Points3& a, const Points3& b, const Vec2& camera_xy,
                                  double bin_m = 0.01);

/// Instance `drop` joins `keep` (keep < drop): its voxels take `keep`'s label, labels above
/// `drop` move down by one, and the centre becomes the two centres' mean weighted by their
/// voxels. std::invalid_argument for indices out of order or range.
void joinInstances(InstanceSegmentation* seg, int keep, int drop);

/// Joins, pair by pair (the closest fit first), instances whose depth points are one open
/// container by the `container_*` fields (the points are given to the instance of their nearest
/// labelled voxel; `camera_table` is the view's camera position). Labels are renumbered densely;
/// a joined centre is the two centres' mean weighted by their voxels. Returns the number of joins.
int joinOpenContainers(const Points3& points_table, const Vec3& camera_table,
                       const SurfaceInstanceConfig& config, InstanceSegmentation* seg);

/// joinOpenContainers for the pairs of instances that an earlier perception held as one object,
/// within `config.held_container_profile_m`: `held` holds that perception's objects' depth
/// points (table frame), one set per object, and an instance is an object's when more than half
/// of its points lie within 1 cm of that object's points. Returns the number of joins.
int joinHeldContainers(const Points3& points_table, const Vec3& camera_table,
                       const std::vector<Points3>& held, const SurfaceInstanceConfig& config,
                       InstanceSegmentation* seg);

/// Joins, pair by pair (the best-fitting plane first), instances that are one object's faces
/// seen on both sides of a nearer one, by the `occluded_*` fields: the points are given to the
/// instance of their nearest labelled voxel, each instance's largest plane is found by PCL's
/// RANSAC, and the gap between two coplanar faces is looked at through `camera` placed at
/// `T_table_camera`, in the depth of `points_table` (stride-subsampled points are spread over
/// `stride` x `stride` pixels). Returns the number of joins.
int joinOccludedPieces(const Points3& points_table, const PinholeCamera& camera,
                       const Transform& T_table_camera, int stride,
                       const SurfaceInstanceConfig& config, InstanceSegmentation* seg);

/// joinOccludedPieces for the pairs of instances that an earlier perception held as one object
/// (`held` as joinHeldContainers takes it), with faces within `config.held_occluded_plane_m` and
/// without the third-instance test. Returns the number of joins.
int joinHeldOccludedPieces(const Points3& points_table, const PinholeCamera& camera,
                           const Transform& T_table_camera, int stride,
                           const std::vector<Points3>& held, const SurfaceInstanceConfig& config,
                           InstanceSegmentation* seg);

}  // namespace simstack
