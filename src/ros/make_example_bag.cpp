// simstack_make_bag: a rosbag of depth frames, depth/image_rect (16UC1, mm), depth/camera_info
// and tf from the table to the camera, as a depth camera on a robot would publish them: of one
// generated pile seen from a ring of viewpoints (test/data/example_pile.bag was made with the
// defaults; README, "Running in ROS"), or of one depth file repeated (--depth: a real scene
// replayed into the node).
#include <geometry_msgs/TransformStamped.h>
#include <rosbag/bag.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/image_encodings.h>
#include <tf2_eigen/tf2_eigen.h>
#include <tf2_msgs/TFMessage.h>
#include <CLI/CLI.hpp>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstring>
#include <functional>
#include <iostream>
#include <optional>
#include <regex>
#include <utility>

#include "cli_checks.h"
#include "depth_files.h"
#include "simstack/io/staged_output.h"
#include "simstack/offline/piles/pile_generator.h"
#include "simstack/pipeline/scene_perception.h"
#include "simstack/pipeline/table_plane.h"
#include "simstack/render/depth_renderer.h"
#include "simstack_ros/conversions.h"

using namespace simstack;

namespace {

/// Why the camera namespace and frames cannot be used ("" when they can): a namespace of
/// names a replay can subscribe to (the topics are /<camera>/depth/...: letters, digits and
/// underscores, each name starting with a letter), frame ids tf2 takes (no leading '/', no
/// blank), the table and camera frames apart.
std::string badNames(const std::string& camera_ns, const std::string& table_frame,
                     const std::string& camera_frame) {
  if (camera_ns.empty() || table_frame.empty() || camera_frame.empty() ||
      table_frame == camera_frame)
    return "--camera, --table-frame and --camera-frame must not be empty, and the table and "
           "camera frames must differ";
  static const std::regex kNamespace("[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*");
  if (!std::regex_match(camera_ns, kNamespace))
    return "--camera '" + camera_ns +
           "' is not a namespace of ROS names (letters, digits and '_', each name starting "
           "with a letter, joined by '/', no leading '/')";
  for (const auto& [option, frame] : {std::make_pair("--table-frame", &table_frame),
                                      std::make_pair("--camera-frame", &camera_frame)}) {
    if (frame->front() == '/')
      return std::string(option) + " '" + *frame + "': a tf2 frame id has no leading '/'";
    if (std::any_of(frame->begin(), frame->end(),
                    [](unsigned char c) { return std::isspace(c) || std::iscntrl(c); }))
      return std::string(option) + " '" + *frame + "': a frame id holds no blank";
  }
  return "";
}

/// Where the frames go: topics under /<camera>/depth/, tf table -> camera.
struct BagNames {
  std::string camera_ns = "camera", table_frame = "table",
              camera_frame = "camera_depth_optical_frame";
};

/// One frame: tf table -> camera, camera_info and the depth image, all at `stamp`.
void writeFrame(rosbag::Bag* bag, const BagNames& names, int seq, const ros::Time& stamp,
                const PinholeCamera& camera, const Transform& T_table_camera,
                const DepthImage& depth) {
  std_msgs::Header header;
  header.seq = seq;
  header.stamp = stamp;
  header.frame_id = names.camera_frame;
  geometry_msgs::TransformStamped t = tf2::eigenToTransform(T_table_camera);
  t.header.stamp = stamp;
  t.header.frame_id = names.table_frame;
  t.child_frame_id = names.camera_frame;
  tf2_msgs::TFMessage tf;
  tf.transforms.push_back(t);
  bag->write("/tf", stamp, tf);
  bag->write("/" + names.camera_ns + "/depth/camera_info", stamp, cameraInfoMsg(header, camera));
  bag->write("/" + names.camera_ns + "/depth/image_rect", stamp, depthImageMsg(header, depth));
}

/// The depth file's frames: `frames` copies `interval_s` apart, the table from its view file
/// or estimated (RANSAC) as the tools do; says which.
int writeDepthFileFrames(rosbag::Bag* bag, const BagNames& names, const std::string& depth_path,
                         std::optional<double> depth_scale, const std::string& intrinsics,
                         const std::string& pose_path, int frames, double interval_s) {
  const DepthView view = readDepthFileView(depth_path, depth_scale, intrinsics, pose_path, "");
  // What the node would refuse, refused here: a bag of frames it cannot use is no example.
  try {
    checkPerceivableView(view, PerceptionConfig());
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error(depth_path + ": " + e.what());
  }
  Transform T_table_camera = view.T_table_camera.value_or(Transform::Identity());
  if (!view.T_table_camera) {
    TablePlane plane;
    try {
      plane = estimateTablePlane(view.depth, view.camera);
    } catch (const std::exception& e) {
      throw std::runtime_error(depth_path + ": " + e.what() + " (--table-pose gives the table)");
    }
    T_table_camera = plane.T_table_camera;
    std::cout << "table plane estimated from " << depth_path << " (" << plane.inliers << " of "
              << plane.points << " sampled points on it); the camera "
              << T_table_camera.translation().z() << " m above it\n";
  }
  for (int f = 0; f < frames; ++f)
    writeFrame(bag, names, f, ros::Time(1.0 + f * interval_s), view.camera, T_table_camera,
               view.depth);
  return frames;
}

/// A BZ2 bag at `path` (staged for `output`) of the frames `frames` writes; returns their count.
/// rosbag::Bag's destructor closes the bag and throws when that fails too (a full disk), which
/// during an exception's unwinding ends the process: a bag whose writing failed is abandoned,
/// never destroyed, and the caller's staged file goes with its file.
int writeBag(const std::string& path, const std::string& output,
             const std::function<int(rosbag::Bag*)>& frames) {
  auto* bag = new rosbag::Bag(path, rosbag::bagmode::Write);
  int written = 0;
  try {
    bag->setCompression(rosbag::compression::BZ2);
    written = frames(bag);
    bag->close();
  } catch (const rosbag::BagException& e) {
    throw std::runtime_error("cannot write " + output + ": " + e.what());
  }
  delete bag;
  return written;
}

}  // namespace

/// The options of the generated pile's ring of views.
struct RingOptions {
  uint64_t seed = 2021;
  int views = 6, repeats = 2;
  double distance_m = 0.75, elevation_deg = 50.0;
  bool noise = true;
};

/// The ring of views of one generated pile, `repeats` frames each.
int writeRingFrames(rosbag::Bag* bag, const BagNames& names, const RingOptions& o,
                    double interval_s, size_t* objects) {
  const Scene scene = PileGenerator(PileConfig()).generate(o.seed).scene;
  *objects = scene.objects.size();
  const DepthRenderer renderer(scene);
  const Vec3 centre = scene.surfaceCentroid();
  const PinholeCamera camera;
  const double elevation = o.elevation_deg * M_PI / 180.0;
  int frame = 0;
  for (int v = 0; v < o.views; ++v) {
    const double azimuth = 2.0 * M_PI * v / o.views;
    const Vec3 eye =
        centre + o.distance_m * Vec3(std::cos(elevation) * std::cos(azimuth),
                                     std::cos(elevation) * std::sin(azimuth), std::sin(elevation));
    const Transform T_table_camera = lookAt(eye, Vec3(centre.x(), centre.y(), 0.05));
    for (int r = 0; r < o.repeats; ++r, ++frame) {
      const RenderResult image = renderer.render(
          camera, T_table_camera,
          o.noise ? SensorNoiseConfig::kinect(o.seed * 1000 + frame) : SensorNoiseConfig());
      writeFrame(bag, names, frame, ros::Time(1.0 + frame * interval_s), camera, T_table_camera,
                 image.depth);
    }
  }
  return frame;
}

int main(int argc, char** argv) {
  std::string output, depth_path, intrinsics, pose_path;
  BagNames names;
  RingOptions ring;
  int frames = 10;
  double interval_s = 0.5, depth_scale = 0.001;
  CLI::App app{
      "Write a rosbag of depth images (16UC1, mm), camera_info and tf table -> camera, to replay "
      "into the perception node: one generated pile seen from a ring of viewpoints, or one depth "
      "file (--depth) repeated."};
  app.add_option("--output", output, "bag file")->required()->check(WritablePath);
  CLI::Option* depth =
      app.add_option("--depth", depth_path,
                     "a depth file instead of a generated pile: 16-bit PNG, "
                     "32-bit float TIFF in metres, or PCD (as simstack_reconstruct)")
          ->check(CLI::ExistingFile);
  app.add_option("--intrinsics", intrinsics,
                 "with --depth: fx,fy,cx,cy in pixels, optionally followed by width,height (or "
                 "--table-pose)")
      ->needs(depth);
  const CLI::Option* scale_option =
      app.add_option("--depth-scale", depth_scale,
                     "with --depth: metres per unit of a 16-bit PNG (default: the --table-pose "
                     "view file's, else 0.001)")
          ->check(FinitePositive)
          ->needs(depth);
  app.add_option("--table-pose", pose_path,
                 "with --depth: its view file (T_table_camera and intrinsics); without it the "
                 "table plane is estimated from the depth (RANSAC)")
      ->check(CLI::ExistingFile)
      ->needs(depth);
  app.add_option("--frames", frames, "with --depth: frames written")
      ->capture_default_str()
      ->check(CLI::Range(1, 10000))
      ->needs(depth);
  const auto ring_option = [&](CLI::Option* o) {
    return o->capture_default_str()->excludes(depth);
  };
  ring_option(app.add_option("--seed", ring.seed, "pile seed (simstack_generate's scene seeds)"))
      ->transform(SeedNumber);
  ring_option(app.add_option("--views", ring.views, "viewpoints on the ring"))
      ->check(CLI::Range(1, 64));
  ring_option(app.add_option("--repeats", ring.repeats, "frames per viewpoint"))
      ->check(CLI::Range(1, 100));
  app.add_option("--interval", interval_s, "seconds between frames")
      ->capture_default_str()
      ->check(FinitePositive)
      ->check(CLI::Range(0.01, 10.0));
  ring_option(
      app.add_option("--distance", ring.distance_m, "camera distance from the pile's centre (m)"))
      ->check(FinitePositive)
      ->check(CLI::Range(0.3, 3.0));
  ring_option(app.add_option("--elevation", ring.elevation_deg,
                             "camera elevation above the table (degrees)"))
      ->check(FinitePositive)
      ->check(CLI::Range(5.0, 90.0));
  app.add_option("--camera", names.camera_ns, "camera namespace of the topics")
      ->capture_default_str();
  app.add_option("--table-frame", names.table_frame, "tf frame of the table")
      ->capture_default_str();
  app.add_option("--camera-frame", names.camera_frame, "tf frame of the depth camera (optical)")
      ->capture_default_str();
  app.add_flag("--noise,!--no-noise", ring.noise,
               "Kinect-like sensor noise in the generated pile's views (default: on)")
      ->excludes(depth);
  readIntegersInDecimal(app);
  CLI11_PARSE(app, argc, argv);
  const std::string bad = badNames(names.camera_ns, names.table_frame, names.camera_frame);
  if (!bad.empty()) {
    std::cerr << "simstack_make_bag: error: " << bad << "\n";
    return 105;  // as CLI11's refusals of an option's value
  }
  try {
    requireNotAnInput("--output", output, {depth_path, pose_path});
    StagedFile staged(output);  // an earlier bag stays whole until this one is
    size_t objects = 0;
    const int written = writeBag(staged.path(), output, [&](rosbag::Bag* bag) {
      return depth_path.empty()
                 ? writeRingFrames(bag, names, ring, interval_s, &objects)
                 : writeDepthFileFrames(
                       bag, names, depth_path,
                       scale_option->count() ? std::optional<double>(depth_scale) : std::nullopt,
                       intrinsics, pose_path, frames, interval_s);
    });
    staged.commit();
    if (depth_path.empty())
      std::cout << "wrote " << written << " frames (" << ring.views << " viewpoints, " << objects
                << " objects, seed " << ring.seed << ") to " << output << "\n";
    else
      std::cout << "wrote " << written << " frames of " << depth_path << " to " << output << "\n";
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "simstack_make_bag: error: " << e.what() << "\n";
    return 1;
  }
}
