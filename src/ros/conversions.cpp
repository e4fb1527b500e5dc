#include "simstack_ros/conversions.h"

#include <image_geometry/pinhole_camera_model.h>
#include <sensor_msgs/image_encodings.h>
#include <sensor_msgs/point_cloud2_iterator.h>
#include <tf2_eigen/tf2_eigen.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <stdexcept>
#include <string>

#include "simstack/io/image_io.h"
#include "simstack/pipeline/scene_perception.h"

namespace simstack {
namespace {

/// Refuses an image larger than the tools read (kMaxDepthImageSide a side), before any work: an
/// 8192 x 8192 frame would hold the node for half a minute and 3.7 GB.
void requireReadableSize(const sensor_msgs::Image& msg, const std::string& what) {
  if (msg.width > static_cast<uint32_t>(kMaxDepthImageSide) ||
      msg.height > static_cast<uint32_t>(kMaxDepthImageSide))
    throw std::invalid_argument(what + " is " + std::to_string(msg.width) + "x" +
                                std::to_string(msg.height) +
                                ", larger than a depth image can be here (" +
                                std::to_string(kMaxDepthImageSide) + " pixels a side)");
}

}  // namespace

Image<uint8_t> maskFromImage(const sensor_msgs::Image& msg) {
  namespace enc = sensor_msgs::image_encodings;
  if (msg.encoding != enc::MONO8 && msg.encoding != enc::TYPE_8UC1)
    throw std::invalid_argument("mask encoding '" + msg.encoding +
                                "' is not supported (use mono8 or 8UC1, 0 = ignore)");
  if (msg.width == 0 || msg.height == 0) throw std::invalid_argument("mask image is empty");
  requireReadableSize(msg, "mask image");
  if (msg.step < msg.width || msg.data.size() < static_cast<size_t>(msg.step) * msg.height)
    throw std::invalid_argument("mask image holds " + std::to_string(msg.data.size()) +
                                " bytes with step " + std::to_string(msg.step) + ", expected " +
                                std::to_string(static_cast<size_t>(msg.width) * msg.height) +
                                " at least");
  Image<uint8_t> mask(static_cast<int>(msg.width), static_cast<int>(msg.height), 0);
  for (uint32_t v = 0; v < msg.height; ++v)
    std::memcpy(&mask.at(0, static_cast<int>(v)),
                msg.data.data() + static_cast<size_t>(v) * msg.step, msg.width);
  return mask;
}

DepthImage depthFromImage(const sensor_msgs::Image& msg) {
  namespace enc = sensor_msgs::image_encodings;
  const bool mm = msg.encoding == enc::TYPE_16UC1 || msg.encoding == enc::MONO16;
  const bool metres = msg.encoding == enc::TYPE_32FC1;
  if (!mm && !metres) {
    throw std::invalid_argument("depth encoding '" + msg.encoding +
                                "' is not supported (use 16UC1 in mm or 32FC1 in m)");
  }
  if (msg.is_bigendian) throw std::invalid_argument("big-endian depth images are not supported");
  if (msg.width == 0 || msg.height == 0) throw std::invalid_argument("depth image is empty");
  requireReadableSize(msg, "depth image");
  const size_t bytes = mm ? 2 : 4;
  if (msg.step < msg.width * bytes) {
    throw std::invalid_argument("depth image step " + std::to_string(msg.step) +
                                " is smaller than width x " + std::to_string(bytes) + " bytes");
  }
  if (msg.data.size() < static_cast<size_t>(msg.step) * msg.height) {
    throw std::invalid_argument("depth image holds " + std::to_string(msg.data.size()) +
                                " bytes, expected " +
                                std::to_string(static_cast<size_t>(msg.step) * msg.height));
  }
  DepthImage depth(static_cast<int>(msg.width), static_cast<int>(msg.height), 0.0f);
  for (uint32_t v = 0; v < msg.height; ++v) {
    const uint8_t* row = msg.data.data() + static_cast<size_t>(v) * msg.step;
    for (uint32_t u = 0; u < msg.width; ++u) {
      float d;
      if (mm) {
        uint16_t raw;
        std::memcpy(&raw, row + 2 * u, 2);
        d = raw * 0.001f;
      } else {
        std::memcpy(&d, row + 4 * u, 4);
      }
      depth.at(u, v) = validDepth(d) ? d : 0.0f;
    }
  }
  return depth;
}

std::string tf2Frame(const std::string& frame) {
  return !frame.empty() && frame.front() == '/' ? frame.substr(1) : frame;
}

Transform rigidFromTf(const geometry_msgs::TransformStamped& transform) {
  const geometry_msgs::Quaternion& r = transform.transform.rotation;
  const geometry_msgs::Vector3& t = transform.transform.translation;
  Transform T = Transform::Identity();
  T.linear() = Quat(r.w, r.x, r.y, r.z).normalized().toRotationMatrix();
  T.translation() = Vec3(t.x, t.y, t.z);
  return T;
}

PinholeCamera cameraFromInfo(const sensor_msgs::CameraInfo& msg) {
  sensor_msgs::CameraInfo info = msg;
  if (info.P[0] == 0.0 || info.P[5] == 0.0)  // a driver that fills K alone
    info.P = {info.K[0], info.K[1], info.K[2], 0.0,       info.K[3], info.K[4],
              info.K[5], 0.0,       info.K[6], info.K[7], info.K[8], 0.0};
  // image_geometry reads any ROI whose width or height is set and does not check it against
  // the full image: one past its edge would describe pixels the camera does not have.
  sensor_msgs::RegionOfInterest& roi = info.roi;
  const bool has_roi = roi.width != 0 || roi.height != 0 || roi.x_offset != 0 || roi.y_offset != 0;
  if (has_roi &&
      (roi.width == 0 || roi.height == 0 || uint64_t{roi.x_offset} + roi.width > info.width ||
       uint64_t{roi.y_offset} + roi.height > info.height))
    throw std::invalid_argument("camera_info's ROI " + std::to_string(roi.width) + "x" +
                                std::to_string(roi.height) + " at (" +
                                std::to_string(roi.x_offset) + ", " + std::to_string(roi.y_offset) +
                                ") does not lie within its " + std::to_string(info.width) + "x" +
                                std::to_string(info.height) + " image");
  // Binning larger than the image (or its window) leaves no pixel: say so by name, not as the
  // empty camera image_geometry would make of it.
  const uint64_t seen_width = has_roi ? roi.width : info.width,
                 seen_height = has_roi ? roi.height : info.height;
  if (seen_width > 0 && seen_height > 0 &&
      (info.binning_x > seen_width || info.binning_y > seen_height))
    throw std::invalid_argument("camera_info's binning " + std::to_string(info.binning_x) + "x" +
                                std::to_string(info.binning_y) + " is larger than its " +
                                std::to_string(seen_width) + "x" + std::to_string(seen_height) +
                                (has_roi ? " ROI" : " image"));
  // The image is rectified already (depth/image_rect): its ROI is a window of it, not one of
  // the raw image to be carried through the distortion model (image_proc's crop_decimate sets
  // do_rectify when it crops).
  roi.do_rectify = false;
  // The intrinsics of the image as published: the ROI cut out, then the binning applied.
  image_geometry::PinholeCameraModel model;
  try {
    model.fromCameraInfo(info);
  } catch (const image_geometry::Exception& e) {
    throw std::invalid_argument(std::string("camera_info: ") + e.what());
  }
  // The full image's camera catches unit mistakes (normalized intrinsics, a principal point
  // off the image); a window of it may leave out the principal point.
  PinholeCamera full;
  full.width = static_cast<int>(info.width);
  full.height = static_cast<int>(info.height);
  full.fx = info.P[0];
  full.fy = info.P[5];
  full.cx = info.P[2];
  full.cy = info.P[6];
  if (has_roi) full.validate();
  const cv::Size size = model.reducedResolution();
  PinholeCamera c;
  c.width = size.width;
  c.height = size.height;
  c.fx = model.fx();
  c.fy = model.fy();
  c.cx = model.cx();
  c.cy = model.cy();
  c.window = has_roi;
  c.validate();
  return c;
}

namespace {

constexpr int kFloat = sensor_msgs::PointField::FLOAT32;

/// A cloud of `points` points (one row, dense) whose float32 fields `set` declares on the
/// modifier, x first; `fill` writes them through an iterator at x (putFloats), when there are
/// any (the iterator needs a point to start at).
template <class SetFields, class Fill>
sensor_msgs::PointCloud2 floatCloud(const std_msgs::Header& header, size_t points, SetFields set,
                                    Fill fill) {
  sensor_msgs::PointCloud2 cloud;
  cloud.header = header;
  cloud.is_dense = true;
  sensor_msgs::PointCloud2Modifier modifier(cloud);
  set(modifier);
  modifier.resize(points);
  if (points == 0) return cloud;
  sensor_msgs::PointCloud2Iterator<float> at(cloud, "x");
  fill(&at);
  return cloud;
}

/// Writes the next point's consecutive float32 fields, from the one `at` points to.
void putFloats(sensor_msgs::PointCloud2Iterator<float>* at, std::initializer_list<float> v) {
  size_t k = 0;
  for (const float f : v) (*at)[k++] = f;
  ++*at;
}

/// rviz's packed rgb: 0x00RRGGBB read as the bytes of a float.
float packedColour(int k) {
  const Eigen::Vector3f c = instanceColour(k) * 255.0f;
  const uint32_t rgb = static_cast<uint32_t>(c.x()) << 16 | static_cast<uint32_t>(c.y()) << 8 |
                       static_cast<uint32_t>(c.z());
  float f;
  std::memcpy(&f, &rgb, 4);
  return f;
}

std_msgs::ColorRGBA colourMsg(int k) {
  const Eigen::Vector3f c = instanceColour(k);
  std_msgs::ColorRGBA out;
  out.r = c.x();
  out.g = c.y();
  out.b = c.z();
  out.a = 1.0f;
  return out;
}

/// A 16UC1 image (little-endian) whose pixel i is value(i).
template <class Value>
sensor_msgs::Image image16(const std_msgs::Header& header, int width, int height, Value value) {
  sensor_msgs::Image img;
  img.header = header;
  img.width = static_cast<uint32_t>(width);
  img.height = static_cast<uint32_t>(height);
  img.encoding = sensor_msgs::image_encodings::TYPE_16UC1;
  img.is_bigendian = false;
  img.step = 2 * img.width;
  img.data.resize(static_cast<size_t>(img.step) * img.height);
  for (size_t i = 0; i < static_cast<size_t>(width) * height; ++i) {
    const uint16_t v = value(i);
    std::memcpy(img.data.data() + 2 * i, &v, 2);
  }
  return img;
}

}  // namespace

sensor_msgs::Image depthImageMsg(const std_msgs::Header& header, const DepthImage& depth) {
  return image16(header, depth.width, depth.height, [&](size_t i) {
    const float d = depth.pixels[i];
    return validDepth(d) ? static_cast<uint16_t>(std::lround(d * 1000.0f)) : uint16_t{0};
  });
}

sensor_msgs::CameraInfo cameraInfoMsg(const std_msgs::Header& header, const PinholeCamera& c) {
  sensor_msgs::CameraInfo info;
  info.header = header;
  info.width = static_cast<uint32_t>(c.width);
  info.height = static_cast<uint32_t>(c.height);
  info.distortion_model = "plumb_bob";
  info.D.assign(5, 0.0);
  info.K = {c.fx, 0, c.cx, 0, c.fy, c.cy, 0, 0, 1};
  info.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  info.P = {c.fx, 0, c.cx, 0, 0, c.fy, c.cy, 0, 0, 0, 1, 0};
  return info;
}

simstack::Superquadric superquadricMsg(const SuperquadricShape& sq) {
  simstack::Superquadric m;
  m.semi_axes.x = sq.scale_m.x();
  m.semi_axes.y = sq.scale_m.y();
  m.semi_axes.z = sq.scale_m.z();
  m.exponents.x = sq.exponents.x();
  m.exponents.y = sq.exponents.y();
  m.exponents.z = sq.exponents.z();
  m.pose = tf2::toMsg(sq.T_table_object);
  return m;
}

sensor_msgs::PointCloud2 pointCloud(const std_msgs::Header& header, const Points3& points) {
  return floatCloud(
      header, points.size(),
      [](auto& m) { m.setPointCloud2Fields(3, "x", 1, kFloat, "y", 1, kFloat, "z", 1, kFloat); },
      [&](auto* at) {
        for (const Vec3& p : points)
          putFloats(at, {static_cast<float>(p.x()), static_cast<float>(p.y()),
                         static_cast<float>(p.z())});
      });
}

namespace {

/// The published id of object k (see ObjectIds).
uint32_t objectId(const ObjectIds& ids, size_t k) {
  return ids.empty() ? static_cast<uint32_t>(k) : ids[k];
}

void checkIdCount(const ObjectIds& ids, size_t objects) {
  if (!ids.empty() && ids.size() != objects)
    throw std::invalid_argument(std::to_string(ids.size()) + " object ids for " +
                                std::to_string(objects) + " objects");
}

/// The colour index of an id: the palette's colours from 1 on.
int colourIndex(uint32_t id) { return static_cast<int>(id % 1000000u) + 1; }

SuperquadricShape moved(SuperquadricShape sq, const Transform& T) {
  sq.T_table_object = T * sq.T_table_object;
  return sq;
}

Points3 moved(Points3 points, const Transform& T) {
  for (Vec3& p : points) p = T * p;
  return points;
}

/// Triangles per face side of a superquadric's collision and marker mesh.
constexpr int kMeshSubdivisions = 6;

}  // namespace

shape_msgs::Mesh superquadricMesh(const SuperquadricShape& sq) {
  const TriangleMesh m = sq.meshObject(kMeshSubdivisions);
  shape_msgs::Mesh out;
  for (const Vec3& v : m.vertices) {
    geometry_msgs::Point p;
    p.x = v.x();
    p.y = v.y();
    p.z = v.z();
    out.vertices.push_back(p);
  }
  for (const auto& t : m.triangles) {
    shape_msgs::MeshTriangle tri;
    for (int c = 0; c < 3; ++c) tri.vertex_indices[c] = static_cast<uint32_t>(t[c]);
    out.triangles.push_back(tri);
  }
  return out;
}

ObjectArray objectArrayMsg(const std_msgs::Header& header, const SceneEstimate& est, int views,
                           int samples, int symmetries, const ObjectIds& ids,
                           const Transform& T_frame_table) {
  checkIdCount(ids, est.instances().size());
  ObjectArray out;
  out.header = header;
  out.table_pose = tf2::toMsg(est.T_table_camera.inverse());
  out.table_in_frame = tf2::toMsg(T_frame_table);
  out.table_estimated = est.table_estimated;
  out.views = static_cast<uint32_t>(views);
  out.samples = static_cast<uint32_t>(samples);
  out.symmetries = static_cast<uint32_t>(symmetries);
  out.voxel_size_m = static_cast<float>(est.grid.voxel_size_m);
  const StageTimings& t = est.timings;
  out.table_ms = static_cast<float>(t.table_ms);
  out.tsdf_ms = static_cast<float>(t.tsdf_ms);
  out.network_ms = static_cast<float>(t.network_ms);
  out.instances_ms = static_cast<float>(t.instances_ms);
  out.mesh_ms = static_cast<float>(t.mesh_ms);
  out.fitting_ms = static_cast<float>(t.fitting_ms);
  out.total_ms = static_cast<float>(t.total_ms);
  const std::vector<InstanceEstimate>& instances = est.instances();
  for (size_t k = 0; k < instances.size(); ++k) {
    Object o;
    o.id = objectId(ids, k);
    o.superquadric = superquadricMsg(moved(instances[k].superquadric, T_frame_table));
    o.mesh = superquadricMesh(instances[k].superquadric);
    // Every depth point measured on it (the seal is judged there), then the fitter's samples of
    // the surface the camera did not see.
    const InstanceEstimate& e = instances[k];
    Points3 surface = e.measured;
    surface.insert(surface.end(), e.points.begin() + e.measured_points, e.points.end());
    o.surface = pointCloud(header, moved(surface, T_frame_table));
    o.measured_points = static_cast<uint32_t>(e.measured.size());
    o.voxels = static_cast<uint32_t>(instances[k].voxels);
    o.visible_fraction = static_cast<float>(instances[k].visible_fraction);
    o.truncated = instances[k].truncated;
    out.objects.push_back(std::move(o));
  }
  for (size_t h = 1; h < est.hypotheses.size() && est.hypotheses[h].decomposed; ++h) {
    SceneSample hypothesis;
    for (const InstanceEstimate& e : est.hypotheses[h].instances)
      hypothesis.superquadrics.push_back(superquadricMsg(moved(e.superquadric, T_frame_table)));
    out.hypotheses.push_back(std::move(hypothesis));
  }
  return out;
}

sensor_msgs::PointCloud2 instancesCloud(const std_msgs::Header& header, const SceneEstimate& est,
                                        const ObjectIds& ids, const Transform& T_frame_table) {
  checkIdCount(ids, est.instances().size());
  size_t n = 0;
  for (const InstanceEstimate& e : est.instances()) n += e.points.size();
  const auto fields = [](auto& m) {
    m.setPointCloud2Fields(5, "x", 1, kFloat, "y", 1, kFloat, "z", 1, kFloat, "label", 1, kFloat,
                           "rgb", 1, kFloat);
  };
  return floatCloud(header, n, fields, [&](auto* at) {
    for (size_t k = 0; k < est.instances().size(); ++k) {
      const uint32_t id = objectId(ids, k);
      const float rgb = packedColour(colourIndex(id));
      for (const Vec3& q : est.instances()[k].points) {
        const Vec3 p = T_frame_table * q;
        putFloats(at, {static_cast<float>(p.x()), static_cast<float>(p.y()),
                       static_cast<float>(p.z()), static_cast<float>(id) + 1.0f, rgb});
      }
    }
  });
}

sensor_msgs::PointCloud2 occupancyCloud(const std_msgs::Header& header,
                                        const Grid3<float>& probability, double min_probability,
                                        const Transform& T_frame_table) {
  const GridSpec& g = probability.spec;
  std::vector<int> kept;
  for (int i = 0; i < static_cast<int>(probability.data.size()); ++i)
    if (probability.data[i] >= min_probability) kept.push_back(i);
  const auto fields = [](auto& m) {
    m.setPointCloud2Fields(4, "x", 1, kFloat, "y", 1, kFloat, "z", 1, kFloat, "probability", 1,
                           kFloat);
  };
  return floatCloud(header, kept.size(), fields, [&](auto* at) {
    for (const int i : kept) {
      const Vec3i v = g.unravel(i);
      const Vec3 c = T_frame_table * g.voxelCentre(v.x(), v.y(), v.z());
      putFloats(at, {static_cast<float>(c.x()), static_cast<float>(c.y()),
                     static_cast<float>(c.z()), probability.data[i]});
    }
  });
}

visualization_msgs::MarkerArray objectMarkers(const std_msgs::Header& header,
                                              const SceneEstimate& est, const ObjectIds& ids,
                                              const Transform& T_frame_table) {
  checkIdCount(ids, est.instances().size());
  visualization_msgs::MarkerArray out;
  visualization_msgs::Marker clear;
  clear.header = header;
  clear.action = visualization_msgs::Marker::DELETEALL;
  out.markers.push_back(clear);
  for (size_t k = 0; k < est.instances().size(); ++k) {
    const SuperquadricShape& sq = est.instances()[k].superquadric;
    visualization_msgs::Marker mesh;
    mesh.header = header;
    mesh.ns = "superquadrics";
    const uint32_t id = objectId(ids, k);
    mesh.id = static_cast<int>(id);
    mesh.type = visualization_msgs::Marker::TRIANGLE_LIST;
    mesh.action = visualization_msgs::Marker::ADD;
    mesh.pose = tf2::toMsg(T_frame_table * sq.T_table_object);
    mesh.scale.x = mesh.scale.y = mesh.scale.z = 1.0;
    mesh.color = colourMsg(colourIndex(id));
    const TriangleMesh m = sq.meshObject(kMeshSubdivisions);
    for (const auto& t : m.triangles)
      for (int c = 0; c < 3; ++c) {
        geometry_msgs::Point p;
        p.x = m.vertices[t[c]].x();
        p.y = m.vertices[t[c]].y();
        p.z = m.vertices[t[c]].z();
        mesh.points.push_back(p);
      }
    out.markers.push_back(mesh);
    visualization_msgs::Marker text;
    text.header = header;
    text.ns = "labels";
    text.id = static_cast<int>(id);
    text.type = visualization_msgs::Marker::TEXT_VIEW_FACING;
    text.action = visualization_msgs::Marker::ADD;
    // Above the object along the table's up.
    const Vec3 above = T_frame_table *
                       (sq.T_table_object.translation() + Vec3(0, 0, sq.scale_m.maxCoeff() + 0.03));
    text.pose.position.x = above.x();
    text.pose.position.y = above.y();
    text.pose.position.z = above.z();
    text.pose.orientation.w = 1.0;
    text.scale.z = 0.04;
    text.color.r = text.color.g = text.color.b = text.color.a = 1.0f;
    text.text = std::to_string(id);
    out.markers.push_back(text);
  }
  return out;
}

sensor_msgs::Image labelImage(const std_msgs::Header& header, const Image<int>& labels,
                              const ObjectIds& ids) {
  return image16(header, labels.width, labels.height, [&](size_t i) {
    const int k = labels.pixels[i];
    if (k < 0) return uint16_t{0};
    const uint64_t id = ids.empty() ? static_cast<uint64_t>(k)
                                    : (static_cast<size_t>(k) < ids.size() ? ids[k] : 65534u);
    return static_cast<uint16_t>(std::min<uint64_t>(id + 1, 65535));
  });
}

}  // namespace simstack
