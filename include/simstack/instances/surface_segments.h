#pragma once
/// @file surface_segments.h
/// A second instance cue from the observed surface. The depth points above the table are cut
/// into locally convex patches (PCL's supervoxels, then LCCP: Stein et al., "Object
/// partitioning using local convexity", CVPR 2014): two patches are kept apart where they
/// meet along a concave edge, as two convex objects resting on each other do. A Hough instance
/// whose visible surface holds such touching patches is several objects that the votes did
/// not separate; it is split along the patches. Hough instances that share one convex patch
/// are one object that the votes cut, and are joined.
///
/// Which patches of one instance belong together is decided by convexity and visibility: if
/// two patches were one convex object, the object would contain every segment between their
/// points, and none of that may lie in space the camera saw through (in front of the observed
/// depth). Patches whose joint hull the camera saw through are different objects: two boxes
/// meeting at a concave edge, or a box in front of another. Patches whose hull hides behind
/// the observed surface can be one object, for example two sides of a box cut apart by an
/// occluder in front of it, and stay together.
#include <cstdint>
#include <map>
#include <set>
#include <utility>
#include <vector>

#include "simstack/geometry/image.h"
#include "simstack/geometry/pinhole_camera.h"
#include "simstack/geometry/voxel_grid.h"
#include "simstack/instances/hough_voting.h"

namespace simstack {

struct SurfaceSegmentConfig {
  bool enabled = true;                  ///< regroup the Hough instances along the patches
  int pixel_stride = 2;                 ///< every n-th pixel of each row and column
  double voxel_resolution_m = 0.008;    ///< supervoxel octree leaf size
  double seed_resolution_m = 0.03;      ///< supervoxel seed spacing
  double concavity_tolerance_deg = 10;  ///< LCCP: steeper concave edges separate patches
  int min_segment_points = 100;         ///< smaller patches take no part (at the stride)
  /// A patch is part of an instance when it holds at least this share of the instance's
  /// visible points.
  double min_instance_share = 0.1;
  /// A patch is also part of an instance, however few of its points that holds, when the patch
  /// is part of another instance and holds at least this share of the instance's visible
  /// points: a sliver the votes cut off a larger object (1: only when all of them do).
  double fragment_share = 0.5;
  /// An instance with fewer visible points than this (the camera did not see it) is part of the
  /// instance it touches over the most voxel faces: the votes cut it off the hidden side of
  /// an object (0 = off; an instance touching none stays).
  int max_unseen_points = 10;
  /// Two instances that one patch is part of may not join when, across the voxel faces where
  /// they meet, the network's votes point away from the other instance by more than this on
  /// average (per face, the mean of the two unit votes' components along the face normal, each
  /// taken towards the other voxel and negated; -1..1): two objects, each voting for its own
  /// centre, not one object the Hough modes cut, whose votes point across the cut. A third
  /// instance that may join both still links them (1 = off).
  double apart_vote_divergence = 0.2;
  /// Fewer faces shared (with a vote on both sides): the votes are not judged.
  int min_boundary_faces = 4;
  /// Hull points more than this in front of the observed depth are in space seen free.
  double free_space_margin_m = 0.02;
  /// Two groups of patches join when at most this share of their hull's samples is seen free.
  double max_free_share = 0.05;
  int hull_samples = 400;  ///< samples per pair test: points on segments between the groups
  /// Two groups sharing an instance and meeting at a concave edge join, whatever their hull,
  /// when their heights overlap over most of the shorter span and the network's votes of their
  /// visible voxels meet within this distance (m): one object seen from inside (a cup's rim
  /// and inside), not one object resting on another. 0 = off.
  double same_centre_m = 0.01;
  /// Two neighbouring points (at the stride) lie on two surfaces, one in front of the other,
  /// when their depths differ by more than this share of the nearer one (0 = off). A convex
  /// object never hides part of itself, so its visible surface has no such step.
  double depth_jump_ratio = 0.015;
  /// Supervoxels, and then patches, whose neighbouring points in the image are apart by a depth
  /// step in at least this share of the pairs are kept apart: the supervoxels take no part in
  /// each other's convexity, and the patches meet at a separating edge as at a concave one.
  double depth_jump_share = 0.5;
  /// Concave creases of the depth image (concaveCreases) cut patches: two objects that touch
  /// meet in a valley, which a convex object's surface never has; LCCP's supervoxels, several
  /// centimetres wide, average a narrow valley away. The parts of a patch a crease cuts meet
  /// at a concave edge. 0 = off: objects that are not convex (a mug, a bowl, a tool) have
  /// valleys of their own.
  double crease_angle_deg = 0.0;
  int crease_window_px = 7;  ///< side of the square window the surface is averaged over
  int crease_offset_px = 6;  ///< the two normals compared lie this far apart in the image
  void validate() const;     ///< std::invalid_argument naming the field
};

/// The observed surface above the table, cut into convex patches, with the view it came from.
struct SurfaceSegments {
  DepthImage depth;
  PinholeCamera camera;
  Transform T_table_camera = Transform::Identity();
  Points3 points_table;    ///< the depth points used, table frame
  std::vector<int> pixel;  ///< per point: its pixel, v * width + u
  std::vector<int> patch;  ///< per point: its patch, -1 = in no patch (too small)
  int patches = 0;
  /// Patch pairs (a < b) that meet at a concave edge or, with `depth_jump_ratio`, at a depth
  /// step.
  std::vector<std::pair<int, int>> concave_edges;
};

/// Patches of one depth view (std::invalid_argument when the image and camera disagree).
/// Points lower than `min_height_m` above the table are left out, and with `grid` those
/// outside its box (no instance lies there, and PCL's octree asserts on far coordinates).
SurfaceSegments segmentVisibleSurface(const DepthImage& depth, const PinholeCamera& camera,
                                      const Transform& T_table_camera, double min_height_m,
                                      const SurfaceSegmentConfig& config,
                                      const GridSpec* grid = nullptr);

/// LCCP's small-segment rule in a fixed order. PCL's own pass visits the supervoxels in the
/// order of their addresses in memory, so which neighbour absorbs a small segment can differ
/// from run to run; `segmentVisibleSurface` runs LCCP without it and calls this instead.
/// `lccp_segment_of` maps each supervoxel label to its LCCP segment, `adjacency` holds the
/// supervoxel pairs that touch. A segment is named by its lowest supervoxel label and keeps
/// that name as it absorbs others. Lowest name first, a segment of at most `max_small`
/// supervoxels joins its neighbour with the most supervoxels (ties: the lowest name) if that
/// one has at least as many as itself, as in PCL; passes repeat until none joins. Returns each
/// supervoxel's segment; `neighbours` receives the segments that touch.
std::map<std::uint32_t, std::uint32_t> mergeSmallSegments(
    const std::map<std::uint32_t, std::uint32_t>& lccp_segment_of,
    const std::multimap<std::uint32_t, std::uint32_t>& adjacency, size_t max_small,
    std::map<std::uint32_t, std::set<std::uint32_t>>* neighbours);

/// Pixels on a concave crease of the depth image's surface (1; 0 elsewhere and where depth is
/// missing). The surface is the camera-frame points averaged over `crease_window_px` squares;
/// two pixels `crease_offset_px` apart along a row, a column or a diagonal whose normals differ
/// by more than `crease_angle_deg`, and turn towards each other (a valley, not a ridge), mark
/// the pixel between them. With `depth_jump_ratio`, a window whose mean lies farther than this
/// share of the depth from its pixel straddles a depth step; it averages two surfaces into a
/// slope that is on neither, and its pixel has no normal. Returns an image of zeros when
/// `crease_angle_deg` is 0.
Image<uint8_t> concaveCreases(const DepthImage& depth, const PinholeCamera& camera,
                              const SurfaceSegmentConfig& config);

/// Linear index of the labelled voxel (label >= 0) nearest to a table-frame point among the
/// point's voxel and those within `reach` voxels along each axis (by default the 26 around it),
/// -1 if none: an observed point lies up to a voxel off the predicted surface.
int nearestLabelledVoxel(const Grid3<int>& labels, const Vec3& p_table, int reach = 1);

/// Share of `hull_samples` points on segments between point sets `a` and `b` (indices into
/// `s.points_table`) that lie in space the view saw free; points off the image or on missing
/// depth are not counted (0 when none is counted).
double seenFreeShare(const SurfaceSegments& s, const std::vector<int>& a, const std::vector<int>& b,
                     const SurfaceSegmentConfig& config, uint64_t seed);

/// The Hough instances regrouped along the patches (see the file comment); `votes` (the grid of
/// `hough.labels`, else std::invalid_argument) enables the vote test below.
/// - First, an instance the camera did not see (fewer than `max_unseen_points` visible points)
///   joins the instance it touches most.
/// - A patch is part of an instance when it holds at least `min_instance_share` of the
///   instance's visible points (and `min_segment_points`), or, when it is part of another
///   instance, `fragment_share` of them.
///   A patch that is part of several instances joins them unless their votes diverge where
///   they meet (`apart_vote_divergence`, with `votes`); the patch then stays with the ones
///   holding most of its points.
/// - Patches start as groups; two groups that are part of a common instance join when they do
///   not meet at a concave edge and at most `max_free_share` of their hull is seen free, or,
///   meeting at one, when their heights overlap and the votes of their visible voxels meet
///   within `same_centre_m` (with `votes`: a cup's rim and inside); the latter pairs first, then
///   the least free.
/// - Each voxel of an instance goes to the group whose visible voxels it reaches first through
///   voxels of the same instance (6-connected); voxels no group reaches, and the voxels of a
///   group left with fewer than `min_part_voxels`, go to the group holding most of the
///   instance. Instances with no group (unseen, or seen in small patches only) stay as they are.
/// So an instance holding two objects is split, and two instances that share one convex patch
/// (one object cut by the votes) are joined. Centres are the new parts' voxel means.
/// Hidden voxels follow the visible surface, not the votes: of a box resting on a wider one,
/// the upper part takes the lower box's middle under it (the paper's assignment rule to the
/// groups' vote centres fixed that case but scored worse superquadrics and stability on the
/// test sets; docs/experiments.md, "Instances: surface regrouping").
InstanceSegmentation regroupAlongSurfaceSegments(const SurfaceSegments& segments,
                                                 const SurfaceSegmentConfig& config,
                                                 int min_part_voxels,
                                                 const InstanceSegmentation& hough,
                                                 const Grid3<Vec3f>* votes = nullptr);

}  // namespace simstack
