#include "simstack/io/image_io.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <set>
#include <stdexcept>
#include <utility>

#include "simstack/io/yaml_file.h"

namespace simstack {
namespace {

void writeOrThrow(const std::string& path, const cv::Mat& m) {
  bool ok = false;
  try {
    ok = cv::imwrite(path, m);
  } catch (const cv::Exception& e) {
    throw std::runtime_error("cannot write " + path + ": " + e.what());
  }
  if (!ok) throw std::runtime_error("cannot write " + path);
}

}  // namespace

void writeDepthPng(const std::string& path, const DepthImage& depth) {
  cv::Mat m(depth.height, depth.width, CV_16UC1);
  for (int v = 0; v < depth.height; ++v) {
    for (int u = 0; u < depth.width; ++u) {
      const float d = depth.at(u, v);
      m.at<uint16_t>(v, u) =
          validDepth(d) ? static_cast<uint16_t>(std::min(65535.0f, std::round(d * 1000.0f))) : 0;
    }
  }
  writeOrThrow(path, m);
}

namespace {

// The size a PNG or TIFF file declares, read from its header before anything is decoded (a
// 10000 x 10000 image would otherwise take 200 MB before it is refused); {0, 0} when the file
// is neither or its header cannot be read (the decoder then decides).
std::pair<uint32_t, uint32_t> declaredSize(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  unsigned char h[24] = {};
  if (!f.read(reinterpret_cast<char*>(h), sizeof h)) return {0, 0};
  const auto be32 = [](const unsigned char* p) {
    return uint32_t(p[0]) << 24 | uint32_t(p[1]) << 16 | uint32_t(p[2]) << 8 | uint32_t(p[3]);
  };
  if (h[0] == 0x89 && h[1] == 'P' && h[2] == 'N' && h[3] == 'G')
    return {be32(h + 16), be32(h + 20)};
  const bool little = h[0] == 'I' && h[1] == 'I', big = h[0] == 'M' && h[1] == 'M';
  if (!little && !big) return {0, 0};
  const auto read = [&](uint32_t offset, int bytes) -> uint32_t {
    unsigned char b[4] = {};
    f.clear();
    f.seekg(offset);
    if (!f.read(reinterpret_cast<char*>(b), bytes)) return 0;
    uint32_t v = 0;
    for (int i = 0; i < bytes; ++i) v |= uint32_t(b[little ? i : bytes - 1 - i]) << (8 * i);
    return v;
  };
  const uint32_t ifd = read(4, 4), entries = read(ifd, 2);
  uint32_t width = 0, height = 0;
  for (uint32_t e = 0; e < std::min<uint32_t>(entries, 512); ++e) {
    const uint32_t at = ifd + 2 + 12 * e, tag = read(at, 2), type = read(at + 2, 2);
    const uint32_t value = type == 3 ? read(at + 8, 2) : read(at + 8, 4);  // SHORT or LONG
    if (tag == 256) width = value;
    if (tag == 257) height = value;
  }
  return {width, height};
}

// Throws naming the file and the chunk when a PNG chunk declares more bytes than the file
// holds after it: libpng allocates a chunk's declared length before reading it (a 1.6 kB file
// whose text chunk declares 800 MB takes 800 MB before it is refused). Not a PNG: nothing.
void requirePngChunksInFile(const std::string& path) {
  std::ifstream f(path, std::ios::binary | std::ios::ate);
  if (!f) return;
  const uint64_t size = static_cast<uint64_t>(f.tellg());
  unsigned char h[8] = {};
  f.seekg(0);
  if (!f.read(reinterpret_cast<char*>(h), sizeof h) || h[0] != 0x89 || h[1] != 'P' || h[2] != 'N' ||
      h[3] != 'G')
    return;
  // Each chunk: its data's length (4 bytes, big-endian), its type (4), the data, a CRC (4).
  for (uint64_t at = 8; at + 8 <= size;) {
    unsigned char c[8] = {};
    f.seekg(static_cast<std::streamoff>(at));
    if (!f.read(reinterpret_cast<char*>(c), sizeof c)) return;
    const uint64_t length =
        uint64_t(c[0]) << 24 | uint64_t(c[1]) << 16 | uint64_t(c[2]) << 8 | c[3];
    std::string type(reinterpret_cast<const char*>(c + 4), 4);
    for (char& ch : type)
      if (!std::isalpha(static_cast<unsigned char>(ch))) ch = '?';  // a corrupt type, printed
    if (at + 12 + length > size)
      throw std::runtime_error(path + ": its PNG chunk '" + type + "' at byte " +
                               std::to_string(at) + " declares " + std::to_string(length) +
                               " bytes, past the file's end (" + std::to_string(size) +
                               " bytes): a truncated or corrupt PNG");
    if (type == "IEND") return;
    at += 12 + length;
  }
}

/// Throws naming the file when its header declares a side over kMaxDepthImageSide, or a PNG
/// chunk longer than the file.
void requireDeclaredSide(const std::string& path, const std::string& what) {
  requirePngChunksInFile(path);
  const auto [width, height] = declaredSize(path);
  if (width > static_cast<uint32_t>(kMaxDepthImageSide) ||
      height > static_cast<uint32_t>(kMaxDepthImageSide))
    throw std::runtime_error(path + ": " + std::to_string(width) + "x" + std::to_string(height) +
                             " is larger than " + what + " can be here (" +
                             std::to_string(kMaxDepthImageSide) + " pixels a side)");
}

}  // namespace

DepthImage readDepthImage(const std::string& path, std::optional<double> depth_scale,
                          double default_scale_m) {
  const double depth_scale_m = depth_scale.value_or(default_scale_m);
  requireDeclaredSide(path, "a depth image");
  const cv::Mat m = cv::imread(path, cv::IMREAD_UNCHANGED);
  if (m.empty()) throw std::runtime_error("cannot read a depth image from " + path);
  if (m.channels() != 1)
    throw std::runtime_error(path + ": a depth image has one channel, this one has " +
                             std::to_string(m.channels()));
  if (m.cols > kMaxDepthImageSide || m.rows > kMaxDepthImageSide)
    throw std::runtime_error(path + ": " + std::to_string(m.cols) + "x" + std::to_string(m.rows) +
                             " is larger than a depth image can be here (" +
                             std::to_string(kMaxDepthImageSide) + " pixels a side)");
  DepthImage depth(m.cols, m.rows, 0.0f);
  if (m.type() == CV_16UC1) {
    for (int v = 0; v < m.rows; ++v)
      for (int u = 0; u < m.cols; ++u)
        depth.at(u, v) = static_cast<float>(m.at<uint16_t>(v, u) * depth_scale_m);
  } else if (m.type() == CV_32FC1) {
    if (depth_scale)
      throw std::runtime_error(path +
                               " holds 32-bit float depth, in metres: a depth scale applies to "
                               "16-bit images only (leave it out)");
    for (int v = 0; v < m.rows; ++v)
      for (int u = 0; u < m.cols; ++u) depth.at(u, v) = m.at<float>(v, u);
  } else {
    throw std::runtime_error(
        path + ": depth must be 16-bit (mm) or 32-bit float (m), this image is " +
        cv::typeToString(m.type()) + " (" + std::to_string(8 * m.elemSize1()) + "-bit)");
  }
  return depth;
}

void writeMaskPng(const std::string& path, const InstanceImage& mask) {
  cv::Mat m(mask.height, mask.width, CV_8UC1, const_cast<uint8_t*>(mask.pixels.data()));
  writeOrThrow(path, m);
}

void writeLabelsPng(const std::string& path, const Image<int>& instances) {
  cv::Mat m(instances.height, instances.width, CV_16UC1, cv::Scalar(0));
  for (int v = 0; v < instances.height; ++v)
    for (int u = 0; u < instances.width; ++u) {
      const int k = instances.at(u, v);
      if (k > 65534)
        throw std::invalid_argument(path + ": instance " + std::to_string(k) +
                                    " does not fit a 16-bit label");
      m.at<uint16_t>(v, u) = static_cast<uint16_t>(k < 0 ? 0 : k + 1);
    }
  writeOrThrow(path, m);
}

InstanceImage readMaskPng(const std::string& path) {
  requireDeclaredSide(path, "a mask");  // it is compared with a depth image pixel for pixel
  cv::Mat m;
  try {
    m = cv::imread(path, cv::IMREAD_UNCHANGED);
  } catch (const cv::Exception& e) {
    throw std::runtime_error("cannot read an 8-bit mask from " + path + ": " + e.what());
  }
  if (m.empty() || m.type() != CV_8UC1)
    throw std::runtime_error("cannot read an 8-bit mask from " + path);
  InstanceImage mask(m.cols, m.rows, 0);
  for (int v = 0; v < m.rows; ++v)
    for (int u = 0; u < m.cols; ++u) mask.at(u, v) = m.at<uint8_t>(v, u);
  return mask;
}

void writeDepthPicture(const std::string& path, const DepthImage& depth) {
  float lo = 1e9f, hi = 0.0f;
  for (float d : depth.pixels) {
    if (validDepth(d)) {
      lo = std::min(lo, d);
      hi = std::max(hi, d);
    }
  }
  cv::Mat grey(depth.height, depth.width, CV_8UC1, cv::Scalar(0));
  cv::Mat valid(depth.height, depth.width, CV_8UC1, cv::Scalar(0));
  const float range = std::max(hi - lo, 1e-6f);
  for (int v = 0; v < depth.height; ++v) {
    for (int u = 0; u < depth.width; ++u) {
      const float d = depth.at(u, v);
      if (!validDepth(d)) continue;
      grey.at<uint8_t>(v, u) = static_cast<uint8_t>(255.0f * (1.0f - (d - lo) / range));
      valid.at<uint8_t>(v, u) = 255;
    }
  }
  cv::Mat colour;
  cv::applyColorMap(grey, colour, cv::COLORMAP_TURBO);
  colour.setTo(cv::Scalar(0, 0, 0), valid == 0);
  writeOrThrow(path, colour);
}

Eigen::Vector3f instanceColour(int k) {
  if (k == 0) return {0.62f, 0.60f, 0.56f};
  static const float palette[][3] = {
      {0.90f, 0.33f, 0.25f}, {0.25f, 0.55f, 0.90f}, {0.35f, 0.75f, 0.35f}, {0.95f, 0.75f, 0.20f},
      {0.65f, 0.40f, 0.85f}, {0.20f, 0.80f, 0.80f}, {0.95f, 0.55f, 0.75f}, {0.55f, 0.45f, 0.30f}};
  const float* c = palette[(k - 1) % 8];
  return {c[0], c[1], c[2]};
}

namespace {

cv::Mat shadedPicture(const InstanceImage& instances, const Image<Vec3f>& normals_table,
                      const Transform& T_table_camera) {
  if (normals_table.width != instances.width || normals_table.height != instances.height) {
    throw std::invalid_argument("shaded picture needs normals of the mask's size");
  }
  // Light from the camera, raised a little, so that faces pointing up are brighter.
  const Vec3f light =
      (-T_table_camera.linear().col(2) + Vec3(0, 0, 0.6)).normalized().cast<float>();
  cv::Mat img(instances.height, instances.width, CV_8UC3, cv::Scalar(40, 40, 40));
  for (int v = 0; v < instances.height; ++v) {
    for (int u = 0; u < instances.width; ++u) {
      const int k = instances.at(u, v);
      if (k == kNoSurface) continue;
      const float shade = 0.25f + 0.75f * std::max(0.0f, normals_table.at(u, v).dot(light));
      const Eigen::Vector3f c = instanceColour(k) * shade * 255.0f;
      img.at<cv::Vec3b>(v, u) =
          cv::Vec3b(cv::saturate_cast<uint8_t>(c.z()), cv::saturate_cast<uint8_t>(c.y()),
                    cv::saturate_cast<uint8_t>(c.x()));
    }
  }
  return img;
}

}  // namespace

void writeShadedPicture(const std::string& path, const InstanceImage& instances,
                        const Image<Vec3f>& normals_table, const Transform& T_table_camera) {
  writeOrThrow(path, shadedPicture(instances, normals_table, T_table_camera));
}

void writeShadedPicture(const std::string& path, const InstanceImage& instances,
                        const Image<Vec3f>& normals_table, const Transform& T_table_camera,
                        const PinholeCamera& camera, const std::vector<PictureArrow>& arrows) {
  cv::Mat img = shadedPicture(instances, normals_table, T_table_camera);
  const Transform T_camera_table = T_table_camera.inverse();
  // Drawn worst first, so that the best arrows end up on top.
  for (auto a = arrows.rbegin(); a != arrows.rend(); ++a) {
    double u0, v0, u1, v1;
    if (!camera.project(T_camera_table * a->tail_table, &u0, &v0) ||
        !camera.project(T_camera_table * a->tip_table, &u1, &v1))
      continue;
    const Eigen::Vector3f c = a->colour * 255.0f;
    const cv::Scalar bgr(c.z(), c.y(), c.x());
    cv::arrowedLine(img, cv::Point2d(u0, v0), cv::Point2d(u1, v1), cv::Scalar(0, 0, 0), 4,
                    cv::LINE_AA, 0, 0.25);
    cv::arrowedLine(img, cv::Point2d(u0, v0), cv::Point2d(u1, v1), bgr, 2, cv::LINE_AA, 0, 0.25);
    if (!a->label.empty())
      cv::putText(img, a->label, cv::Point2d(u0 + 4, v0 - 4), cv::FONT_HERSHEY_SIMPLEX, 0.5,
                  cv::Scalar(255, 255, 255), 1, cv::LINE_AA);
  }
  writeOrThrow(path, img);
}

void writeViewYaml(const std::string& path, const ViewDescription& view) {
  YAML::Emitter out;
  const Quat q(view.T_table_camera.linear());
  const Vec3 t = view.T_table_camera.translation();
  out << YAML::BeginMap;
  out << YAML::Key << "width" << YAML::Value << view.camera.width;
  out << YAML::Key << "height" << YAML::Value << view.camera.height;
  out << YAML::Key << "intrinsics" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key
      << "fx" << YAML::Value << view.camera.fx << YAML::Key << "fy" << YAML::Value << view.camera.fy
      << YAML::Key << "cx" << YAML::Value << view.camera.cx << YAML::Key << "cy" << YAML::Value
      << view.camera.cy << YAML::EndMap;
  if (view.depth_scale_m) out << YAML::Key << "depth_scale_m" << YAML::Value << *view.depth_scale_m;
  out << YAML::Key << "T_table_camera" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "translation" << YAML::Value << YAML::Flow << YAML::BeginSeq << t.x() << t.y()
      << t.z() << YAML::EndSeq;
  out << YAML::Key << "rotation_xyzw" << YAML::Value << YAML::Flow << YAML::BeginSeq << q.x()
      << q.y() << q.z() << q.w() << YAML::EndSeq;
  out << YAML::EndMap << YAML::EndMap;
  std::ofstream f(path);
  if (!f) throw std::runtime_error("cannot write " + path);
  f << "# simstack view: intrinsics (pixels) and T_table_camera (camera-frame points to the table "
       "frame)\n"
    << out.c_str() << "\n";
  if (!f) throw std::runtime_error("cannot write " + path);
}

ViewDescription readViewYaml(const std::string& path) {
  ViewDescription view;
  const YAML::Node n = loadYamlFile(path, "view description");
  if (!n.IsMap())
    throw std::runtime_error("cannot read view description " + path +
                             ": it holds no map of width, height, intrinsics and T_table_camera");
  requireKnownKeys(n, {"width", "height", "intrinsics", "depth_scale_m", "T_table_camera"},
                   "the view description", path);
  for (const char* key : {"width", "height", "intrinsics", "T_table_camera"})
    if (!n[key])
      throw std::runtime_error("cannot read view description " + path + ": it has no " + key);
  if (n["intrinsics"].IsMap())
    requireKnownKeys(n["intrinsics"], {"fx", "fy", "cx", "cy"}, "intrinsics", path);
  if (n["T_table_camera"].IsMap())
    requireKnownKeys(n["T_table_camera"], {"translation", "rotation_xyzw"}, "T_table_camera", path);
  try {
    view.camera.width = n["width"].as<int>();
    view.camera.height = n["height"].as<int>();
    view.camera.fx = n["intrinsics"]["fx"].as<double>();
    view.camera.fy = n["intrinsics"]["fy"].as<double>();
    view.camera.cx = n["intrinsics"]["cx"].as<double>();
    view.camera.cy = n["intrinsics"]["cy"].as<double>();
    if (n["depth_scale_m"]) {
      view.depth_scale_m = n["depth_scale_m"].as<double>();
      if (!(*view.depth_scale_m > 0.0 && std::isfinite(*view.depth_scale_m)))
        throw std::runtime_error("depth_scale_m must be a positive number of metres per unit");
    }
    const auto t = n["T_table_camera"]["translation"].as<std::vector<double>>();
    const auto q = n["T_table_camera"]["rotation_xyzw"].as<std::vector<double>>();
    if (t.size() != 3 || q.size() != 4)
      throw std::runtime_error("translation needs 3 values and rotation_xyzw 4");
    const Vec3 translation(t[0], t[1], t[2]);
    const Quat rotation(q[3], q[0], q[1], q[2]);
    // A camera farther than the sensor range can reach (perception's max_depth_m <= 100 m) from
    // the table sees nothing of it; a zero quaternion is no rotation at all.
    if (!translation.allFinite() || !rotation.coeffs().allFinite())
      throw std::runtime_error("T_table_camera: pose is not finite");
    if (translation.norm() > kMaxCameraDistanceM)
      throw std::runtime_error("T_table_camera.translation places the camera " +
                               std::to_string(translation.norm()) +
                               " m from the table's origin; "
                               "at most " +
                               std::to_string(static_cast<int>(kMaxCameraDistanceM)) +
                               " m is a camera that sees the table");
    if (rotation.norm() < 1e-6)
      throw std::runtime_error(
          "T_table_camera.rotation_xyzw is zero: not a rotation (a unit quaternion x y z w, e.g. "
          "[0, 0, 0, 1] for none)");
    view.T_table_camera = Transform::Identity();
    view.T_table_camera.linear() = rotation.normalized().toRotationMatrix();
    view.T_table_camera.translation() = translation;
  } catch (const YAML::Exception& e) {
    throw std::runtime_error("cannot read view description " + path + ": " + e.what());
  } catch (const std::runtime_error& e) {
    throw std::runtime_error("cannot read view description " + path + ": " + e.what());
  }
  view.camera.validate();
  return view;
}

}  // namespace simstack
