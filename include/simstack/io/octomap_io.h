#pragma once
/// @file octomap_io.h
/// Occupancy grids as OctoMap files (liboctomap), for planners and octovis.

#include <string>

#include "simstack/geometry/voxel_grid.h"

namespace simstack {

/// Writes the per-voxel occupancy probability on its grid (table frame) as an OctoMap with the
/// grid's voxel size. `.ot`: an OcTree whose leaves hold each voxel's probability (as log-odds);
/// `.bt`: the compact binary form, where a voxel is occupied when its probability is at least
/// `min_probability` and free otherwise. The file is written beside `path` and renamed into
/// place, so a reader never sees half of it and an existing file is replaced whole. Throws
/// std::invalid_argument for another extension or a probability grid of the wrong size, and
/// std::runtime_error naming the file when it cannot be written.
void writeOccupancyOctomap(const std::string& path, const Grid3<float>& probability,
                           double min_probability);

}  // namespace simstack
