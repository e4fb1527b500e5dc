#pragma once
/// @file convex_split.h
/// Splitting instances that no single convex shape explains: a variant measured and not kept
/// (`HoughConfig::experimental`, off in every shipped setting). Hough voting merges two touching
/// objects into one instance when their votes do not separate them; the union of two convex
/// objects is, as a rule, far from convex (an L, a step), while one object, which is what a
/// superquadric describes, is close to convex. The measure is solidity: an instance's voxels
/// over the grid voxels whose centres lie in the convex hull of its voxel centres (1 for a
/// convex set of voxels). An instance below `experimental.split_below_solidity` is cut by the
/// plane, among cuts across the grid axes and its principal axes at several quantiles, after which
/// the two parts are most solid together; the cut is kept when that joint solidity reaches
/// `split_accept_solidity`, and the parts are tested again in the next round (at most
/// `split_max_rounds` rounds; a part whose cut was refused is not tested again).

#include <vector>

#include "simstack/instances/hough_voting.h"

namespace simstack {

/// Voxels of the set over grid voxels inside the convex hull of their centres, in (0, 1].
/// Sets whose centres span no volume (flat, fewer than 4 voxels) count as convex (1).
double voxelSolidity(const std::vector<Vec3i>& voxels, const GridSpec& grid);

/// Applies the split test of the file comment to every instance of `seg` (labels, centres and
/// counts updated, largest instance first again). Parts smaller than
/// `config.min_instance_voxels` are never made. Returns the number of cuts made.
int splitNonConvexInstances(InstanceSegmentation* seg, const HoughConfig& config);

}  // namespace simstack
