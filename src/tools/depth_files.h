#pragma once
/// @file depth_files.h
/// A depth file as the tools read it (simstack_reconstruct, simstack_make_bag): a 16-bit PNG
/// (units of the depth scale), a 32-bit float TIFF in metres, or a PCD (an unorganized cloud is
/// placed on the pixels of the given camera), with its camera and, from a view file, its table
/// pose.

#include <optional>
#include <string>

#include "simstack/geometry/depth_view.h"

namespace simstack {

/// The view of `depth_path`: its camera from `intrinsics` ("fx,fy,cx,cy") or the view file
/// `pose_path` (a simstack_generate view .yaml: intrinsics and T_table_camera; "" for none),
/// the mask PNG `mask_path` ("" for none). std::invalid_argument naming the file or option
/// when they disagree or are missing; the readers' errors for unreadable files.
DepthView readDepthFileView(const std::string& depth_path, std::optional<double> depth_scale,
                            const std::string& intrinsics, const std::string& pose_path,
                            const std::string& mask_path);

}  // namespace simstack
