#include "depth_files.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <stdexcept>

#include "perception_options.h"
#include "simstack/io/image_io.h"
#include "simstack/io/scene_io.h"

namespace simstack {

namespace fs = std::filesystem;

DepthView readDepthFileView(const std::string& depth_path, std::optional<double> depth_scale,
                            const std::string& intrinsics, const std::string& pose_path,
                            const std::string& mask_path) {
  DepthView view;
  std::optional<ViewDescription> pose;
  if (!pose_path.empty()) pose = readViewYaml(pose_path);
  std::string ext = fs::path(depth_path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), ::tolower);
  if (ext == ".pcd") {
    if (depth_scale)
      throw std::invalid_argument("--depth-scale applies to 16-bit PNGs; " + depth_path +
                                  " is a point cloud, in metres (leave it out)");
    // An unorganized cloud is placed on the pixels of the view file's camera, else of the
    // intrinsics over the image their principal point centres.
    std::optional<PinholeCamera> organizer;
    if (pose)
      organizer = pose->camera;
    else if (!intrinsics.empty())
      organizer = parseCentredIntrinsics(intrinsics);
    view.depth = readDepthPcd(depth_path, organizer ? &*organizer : nullptr);
  } else {
    // The view file's depth_scale_m, unless --depth-scale says otherwise; two different
    // scales for one image are refused, not chosen between.
    if (pose && pose->depth_scale_m && depth_scale &&
        std::abs(*pose->depth_scale_m - *depth_scale) > 1e-12 * *depth_scale)
      throw std::invalid_argument("--depth-scale " + std::to_string(*depth_scale) +
                                  " differs from " + pose_path + "'s depth_scale_m " +
                                  std::to_string(*pose->depth_scale_m) + ": give one of them");
    // The view file's scale is its 16-bit PNG's: a float TIFF in metres given with it is read.
    view.depth =
        readDepthImage(depth_path, depth_scale,
                       pose && pose->depth_scale_m ? *pose->depth_scale_m : kDefaultDepthScaleM);
  }
  if (!intrinsics.empty())
    view.camera = parseIntrinsics(intrinsics, view.depth.width, view.depth.height);
  else if (pose_path.empty())
    throw std::invalid_argument("--intrinsics is needed for " + depth_path +
                                " (or a --table-pose view file, which holds them)");
  if (pose) {
    if (pose->camera.width != view.depth.width || pose->camera.height != view.depth.height)
      throw std::invalid_argument(pose_path + " describes a " + std::to_string(pose->camera.width) +
                                  "x" + std::to_string(pose->camera.height) + " view, but " +
                                  depth_path + " is " + std::to_string(view.depth.width) + "x" +
                                  std::to_string(view.depth.height));
    const PinholeCamera& c = pose->camera;
    if (intrinsics.empty())
      view.camera = c;
    else if (std::abs(c.fx - view.camera.fx) > 1e-6 || std::abs(c.fy - view.camera.fy) > 1e-6 ||
             std::abs(c.cx - view.camera.cx) > 1e-6 || std::abs(c.cy - view.camera.cy) > 1e-6)
      throw std::invalid_argument("--intrinsics " + intrinsics + " differ from those of " +
                                  pose_path + " (" + std::to_string(c.fx) + "," +
                                  std::to_string(c.fy) + "," + std::to_string(c.cx) + "," +
                                  std::to_string(c.cy) + "): give one of them");
    view.T_table_camera = pose->T_table_camera;
  }
  if (!mask_path.empty()) {
    view.mask = readMaskPng(mask_path);
    if (view.mask.width != view.depth.width || view.mask.height != view.depth.height)
      throw std::invalid_argument(mask_path + " is " + std::to_string(view.mask.width) + "x" +
                                  std::to_string(view.mask.height) + ", but " + depth_path +
                                  " is " + std::to_string(view.depth.width) + "x" +
                                  std::to_string(view.depth.height));
  }
  return view;
}

}  // namespace simstack
