#pragma once
/// @file reconstruction_files.h
/// The files of one reconstruction (simstack_reconstruct): superquadrics.yaml, instance_K.ply,
/// surface.ply, instances.pcd (x y z label; 0 = table or unassigned, k + 1 = instance k),
/// labels.png (16-bit, aligned with the input depth: 0 none, k + 1 instance k, the id k of
/// superquadrics.yaml), grids.h5 and PNG pictures (the input depth, the instances on it, the
/// superquadrics from the input view and from a second view turned 90 degrees about the pile's
/// vertical axis).

#include <string>
#include <vector>

#include "simstack/pipeline/scene_perception.h"

namespace simstack {

/// Writes the files of hypothesis 0 of `estimate` (perceived from `view`) into `dir`, which
/// must exist; pixels lower than `label_min_height_m` above the table are no instance's
/// (labelMinHeight). With `one_view` (the estimate fused no other), superquadrics.yaml names
/// the camera that measured the objects' points. Returns the names written. Throws
/// std::runtime_error naming a file it cannot write.
std::vector<std::string> writeReconstruction(const std::string& dir, const DepthView& view,
                                             const SceneEstimate& estimate,
                                             double label_min_height_m, bool one_view = true);

}  // namespace simstack
