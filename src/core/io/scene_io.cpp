#include "simstack/io/scene_io.h"

#include <H5Cpp.h>
#include <pcl/PolygonMesh.h>
#include <pcl/conversions.h>
#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>
#include <pcl/point_types.h>
#include <yaml-cpp/yaml.h>

#include <Eigen/Cholesky>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <sstream>
#include <stdexcept>

#include "simstack/io/yaml_file.h"

namespace simstack {
namespace {

std::vector<double> seq(const YAML::Node& n, size_t size, const std::string& what,
                        const std::string& path) {
  if (!n || !n.IsSequence() || n.size() != size)
    throw std::runtime_error(path + ": '" + what + "' must be a list of " + std::to_string(size) +
                             " numbers");
  std::vector<double> v;
  try {
    for (const auto& x : n) v.push_back(x.as<double>());
  } catch (const YAML::Exception&) {
    throw std::runtime_error(path + ": '" + what + "' must be a list of " + std::to_string(size) +
                             " numbers (line " + std::to_string(n.Mark().line + 1) + ")");
  }
  return v;
}

}  // namespace

void writeSuperquadricsYaml(const std::string& path, const std::vector<SuperquadricShape>& shapes,
                            const std::string& frame, const std::vector<bool>& truncated,
                            const std::optional<Vec3>& camera) {
  if (!truncated.empty() && truncated.size() != shapes.size())
    throw std::invalid_argument("writeSuperquadricsYaml: one truncated flag per shape");
  YAML::Emitter out;
  out << YAML::BeginMap << YAML::Key << "frame" << YAML::Value << frame;
  if (camera)
    out << YAML::Key << "camera" << YAML::Value << YAML::Flow
        << std::vector<double>{camera->x(), camera->y(), camera->z()};
  out << YAML::Key << "objects" << YAML::Value << YAML::BeginSeq;
  for (size_t i = 0; i < shapes.size(); ++i) {
    const SuperquadricShape& s = shapes[i];
    const Quat q(s.T_table_object.linear());
    const Vec3 t = s.T_table_object.translation();
    out << YAML::BeginMap << YAML::Key << "id" << YAML::Value << i;
    out << YAML::Key << "scale" << YAML::Value << YAML::Flow
        << std::vector<double>{s.scale_m.x(), s.scale_m.y(), s.scale_m.z()};
    out << YAML::Key << "exponents" << YAML::Value << YAML::Flow
        << std::vector<double>{s.exponents.x(), s.exponents.y(), s.exponents.z()};
    out << YAML::Key << "position" << YAML::Value << YAML::Flow
        << std::vector<double>{t.x(), t.y(), t.z()};
    out << YAML::Key << "orientation" << YAML::Value << YAML::Flow
        << std::vector<double>{q.w(), q.x(), q.y(), q.z()};
    if (!truncated.empty()) out << YAML::Key << "truncated" << YAML::Value << truncated[i];
    out << YAML::EndMap;
  }
  out << YAML::EndSeq << YAML::EndMap;
  std::ofstream f(path);
  if (!f) throw std::runtime_error("cannot write " + path);
  f << "# superquadrics (SIMstack eq. 4): scale = semi-axes a1..a3 in m, exponents r s t,\n"
       "# pose T_table_object as position + orientation quaternion [w, x, y, z]\n"
    << out.c_str() << "\n";
  if (!f) throw std::runtime_error("cannot write " + path);
}

std::vector<SuperquadricShape> readSuperquadricsYaml(const std::string& path, std::vector<int>* ids,
                                                     std::optional<Vec3>* camera) {
  const YAML::Node root = loadYamlFile(path, "superquadrics");
  if (!root.IsMap() || !root["objects"] || !root["objects"].IsSequence())
    throw std::runtime_error(path + ": no 'objects' list");
  requireKnownKeys(root, {"frame", "camera", "objects"}, "the file", path);
  if (root["frame"] && !root["frame"].IsScalar())
    throw std::runtime_error(path + ": frame is not a name (the table frame the file is in)");
  if (camera) {
    camera->reset();
    if (root["camera"]) {
      const auto c = seq(root["camera"], 3, "camera", path);
      *camera = Vec3(c[0], c[1], c[2]);
      if (!camera->value().allFinite())
        throw std::runtime_error(path + ": camera has a value that is not finite");
      // The table is z = 0: a camera at or below it measured no pile.
      if (!(camera->value().z() > 0.0))
        throw std::runtime_error(path + ": camera is at z = " + std::to_string(c[2]) +
                                 ", at or below the table (z = 0), where no camera sees the pile");
    }
  }
  std::vector<SuperquadricShape> out;
  std::set<int> seen_ids;
  for (const auto& o : root["objects"]) {
    const std::string which = "object " + std::to_string(out.size());
    if (!o.IsMap()) throw std::runtime_error(path + ": " + which + " is not a map");
    requireKnownKeys(o, {"id", "scale", "exponents", "position", "orientation", "truncated"}, which,
                     path);
    if (o["truncated"]) {
      bool truncated = false;
      if (!o["truncated"].IsScalar() || !YAML::convert<bool>::decode(o["truncated"], truncated))
        throw std::runtime_error(path + ": " + which + "'s truncated is not true or false");
    }
    const auto a = seq(o["scale"], 3, "scale", path), e = seq(o["exponents"], 3, "exponents", path),
               p = seq(o["position"], 3, "position", path),
               q = seq(o["orientation"], 4, "orientation", path);
    SuperquadricShape s;
    s.scale_m = Vec3(a[0], a[1], a[2]);
    s.exponents = Vec3(e[0], e[1], e[2]);
    if ((s.scale_m.array() <= 0).any() || (s.exponents.array() <= 0).any())
      throw std::runtime_error(path + ": " + which + ": scales and exponents must be positive");
    Quat quat(q[0], q[1], q[2], q[3]);
    if (quat.norm() < 1e-9)
      throw std::runtime_error(path + ": " + which + ": zero orientation quaternion");
    s.T_table_object = Transform::Identity();
    s.T_table_object.linear() = quat.normalized().toRotationMatrix();
    s.T_table_object.translation() = Vec3(p[0], p[1], p[2]);
    if (!s.T_table_object.matrix().allFinite() || !s.scale_m.allFinite() ||
        !s.exponents.allFinite())
      throw std::runtime_error(path + ": object " + std::to_string(out.size()) +
                               " has a value that is not finite");
    if (ids) {
      try {
        ids->push_back(o["id"] ? o["id"].as<int>() : static_cast<int>(out.size()));
      } catch (const YAML::Exception&) {
        throw std::runtime_error(path + ": object " + std::to_string(out.size()) +
                                 " has an id that is not an integer");
      }
      if (ids->back() < 0)
        throw std::runtime_error(path + ": object " + std::to_string(out.size()) + " has id " +
                                 std::to_string(ids->back()) + ": ids are 0 or more");
      if (!seen_ids.insert(ids->back()).second)
        throw std::runtime_error(path + ": id " + std::to_string(ids->back()) + " is given twice");
    }
    out.push_back(s);
  }
  return out;
}

void writeMeshPly(const std::string& path, const TriangleMesh& mesh) {
  if (mesh.vertices.empty()) {  // PCL refuses to write an empty mesh; an empty PLY is valid
    std::ofstream f(path);
    f << "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
         "property float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n";
    if (!f) throw std::runtime_error("cannot write " + path);
    return;
  }
  pcl::PointCloud<pcl::PointXYZ> cloud;
  for (const Vec3& v : mesh.vertices) cloud.push_back(pcl::PointXYZ(v.x(), v.y(), v.z()));
  pcl::PolygonMesh pm;
  pcl::toPCLPointCloud2(cloud, pm.cloud);
  for (const auto& t : mesh.triangles) {
    pcl::Vertices f;
    f.vertices = {static_cast<pcl::index_t>(t[0]), static_cast<pcl::index_t>(t[1]),
                  static_cast<pcl::index_t>(t[2])};
    pm.polygons.push_back(f);
  }
  if (pcl::io::savePLYFileBinary(path, pm) != 0) throw std::runtime_error("cannot write " + path);
}

TriangleMesh readMeshPly(const std::string& path) {
  pcl::PolygonMesh pm;
  if (pcl::io::loadPLYFile(path, pm) != 0) throw std::runtime_error("cannot read mesh " + path);
  pcl::PointCloud<pcl::PointXYZ> cloud;
  pcl::fromPCLPointCloud2(pm.cloud, cloud);
  TriangleMesh mesh;
  for (const auto& p : cloud) mesh.vertices.emplace_back(p.x, p.y, p.z);
  for (const auto& f : pm.polygons) {
    if (f.vertices.size() != 3) throw std::runtime_error(path + ": only triangle meshes are read");
    for (uint32_t i : f.vertices)
      if (i >= mesh.vertices.size()) throw std::runtime_error(path + ": vertex index out of range");
    mesh.triangles.emplace_back(f.vertices[0], f.vertices[1], f.vertices[2]);
  }
  return mesh;
}

void writeLabelledCloudPcd(const std::string& path, const Points3& points,
                           const std::vector<int>& labels) {
  if (labels.size() != points.size())
    throw std::invalid_argument("writeLabelledCloudPcd: one label per point is required");
  pcl::PointCloud<pcl::PointXYZL> cloud;
  for (size_t i = 0; i < points.size(); ++i) {
    pcl::PointXYZL p;
    p.x = points[i].x();
    p.y = points[i].y();
    p.z = points[i].z();
    p.label = static_cast<uint32_t>(std::max(labels[i], 0));
    cloud.push_back(p);
  }
  if (cloud.empty()) {  // PCL refuses to write an empty cloud; an empty file is still valid
    cloud.width = 0;
    cloud.height = 1;
    std::ofstream f(path);
    f << "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z label\n"
         "SIZE 4 4 4 4\nTYPE F F F U\nCOUNT 1 1 1 1\nWIDTH 0\nHEIGHT 1\n"
         "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 0\nDATA ascii\n";
    if (!f) throw std::runtime_error("cannot write " + path);
    return;
  }
  try {
    if (pcl::io::savePCDFileBinary(path, cloud) != 0)
      throw std::runtime_error("cannot write " + path);
  } catch (const pcl::IOException& e) {  // a full disk, say
    throw std::runtime_error("cannot write " + path + ": " + e.detailedMessage());
  }
}

namespace {

/// The labelled cloud at `path` (its header checked by the caller), refused by name when the
/// file has no label field: PCL would fill it with zeros after a warning.
pcl::PointCloud<pcl::PointXYZL> readLabelledCloud(const std::string& path) {
  pcl::PCLPointCloud2 blob;
  if (pcl::io::loadPCDFile(path, blob) != 0)
    throw std::runtime_error("cannot read the labelled cloud " + path);
  if (std::none_of(blob.fields.begin(), blob.fields.end(),
                   [](const pcl::PCLPointField& f) { return f.name == "label"; }))
    throw std::runtime_error(path +
                             " has no label field (x y z label, as simstack_reconstruct "
                             "writes instances.pcd)");
  pcl::PointCloud<pcl::PointXYZL> cloud;
  pcl::fromPCLPointCloud2(blob, cloud);
  return cloud;
}

}  // namespace

Points3 readLabelledPoints(const std::string& path, uint32_t label) {
  checkPcdHeader(path);
  const pcl::PointCloud<pcl::PointXYZL> cloud = readLabelledCloud(path);
  Points3 out;
  for (const pcl::PointXYZL& p : cloud)
    if (p.label == label && std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z))
      out.emplace_back(p.x, p.y, p.z);
  return out;
}

void checkPcdHeader(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) throw std::runtime_error("cannot open " + path);
  f.seekg(0, std::ios::end);
  const long long file_size = f.tellg();
  f.seekg(0);
  const auto bad = [&](const std::string& why) {
    return std::runtime_error(path + " is not a PCD file PCL can read safely: " + why);
  };
  std::map<std::string, std::vector<std::string>> header;
  std::string line;
  // The header is text lines up to DATA; a real one is a few hundred bytes.
  while (f.tellg() < 65536 && std::getline(f, line)) {
    if (line.empty() || line[0] == '#') continue;
    for (const unsigned char c : line)  // PCL's header parser crashes on some stray bytes
      if (c != '\r' && c != '\t' && (c < 32 || c > 126))
        throw bad("a byte that is not text in its header");
    std::istringstream words(line);
    std::string key, word;
    words >> key;
    static const std::set<std::string> known{"VERSION", "FIELDS", "SIZE",      "TYPE",   "COUNT",
                                             "WIDTH",   "HEIGHT", "VIEWPOINT", "POINTS", "DATA"};
    if (!known.count(key)) throw bad("'" + key.substr(0, 20) + "' is not a header field");
    while (words >> word) header[key].push_back(word);
    if (key == "DATA") break;
  }
  if (!header.count("DATA")) throw bad("no DATA line in its first 64 KB");
  for (const char* key : {"FIELDS", "SIZE", "TYPE", "WIDTH", "HEIGHT"})
    if (!header.count(key)) throw bad(std::string("no ") + key + " line");
  const auto& fields = header["FIELDS"];
  const size_t n = fields.size();
  std::vector<std::string> counts =
      header.count("COUNT") ? header["COUNT"] : std::vector<std::string>(n, "1");
  if (header["SIZE"].size() != n || header["TYPE"].size() != n || counts.size() != n)
    throw bad("FIELDS, SIZE, TYPE and COUNT differ in length");
  for (const char* axis : {"x", "y", "z"})
    if (std::find(fields.begin(), fields.end(), axis) == fields.end())
      throw bad(std::string("no field ") + axis);
  const auto number = [&](const std::string& text, long long lo, long long hi, const char* what) {
    size_t used = 0;
    long long v = -1;
    try {
      v = std::stoll(text, &used);
    } catch (const std::exception&) {
    }
    if (used != text.size() || v < lo || v > hi)
      throw bad(std::string(what) + " '" + text + "' is not in [" + std::to_string(lo) + ", " +
                std::to_string(hi) + "]");
    return v;
  };
  long long point_bytes = 0, values_per_point = 0;
  for (size_t i = 0; i < n; ++i) {
    const long long size = number(header["SIZE"][i], 1, 8, "SIZE");
    const std::string& type = header["TYPE"][i];
    const bool ok = type == "F" ? (size == 4 || size == 8)
                                : (type == "I" || type == "U") &&
                                      (size == 1 || size == 2 || size == 4 || size == 8);
    if (!ok) throw bad("TYPE " + type + " of SIZE " + std::to_string(size) + " is not a PCD field");
    point_bytes += size * number(counts[i], 1, 1024, "COUNT");
    values_per_point += number(counts[i], 1, 1024, "COUNT");
  }
  // An unorganized cloud (HEIGHT 1) may hold up to a largest image's points in one row.
  const long long height = number(header["HEIGHT"].at(0), 1, kMaxDepthImageSide, "HEIGHT");
  const long long max_width = height == 1
                                  ? static_cast<long long>(kMaxDepthImageSide) * kMaxDepthImageSide
                                  : kMaxDepthImageSide;
  const long long width = number(header["WIDTH"].at(0), 1, max_width, "WIDTH");
  if (header.count("POINTS") &&
      number(header["POINTS"].at(0), 0, width * height, "POINTS") != width * height)
    throw bad("POINTS differs from WIDTH x HEIGHT");
  const std::string data = header["DATA"].empty() ? "" : header["DATA"][0];
  const long long body = file_size - static_cast<long long>(f.tellg());
  if (data == "binary") {
    if (body < width * height * point_bytes)
      throw bad("its binary data holds " + std::to_string(body) + " bytes, not the " +
                std::to_string(width * height * point_bytes) + " its header promises");
  } else if (data == "binary_compressed") {
    uint32_t sizes[2] = {0, 0};
    f.read(reinterpret_cast<char*>(sizes), sizeof sizes);
    if (!f || sizes[0] > body - 8 || sizes[1] != width * height * point_bytes)
      throw bad("its compressed data sizes do not match the header");
  } else if (data == "ascii") {
    // PCL's text parser crashes on short or ragged lines: every point must be a line of
    // exactly the header's number of values.
    long long points = 0;
    while (std::getline(f, line)) {
      std::istringstream values(line);
      std::string value;
      long long count = 0;
      while (values >> value) {
        char* end = nullptr;
        std::strtod(value.c_str(), &end);
        if (*end != '\0') throw bad("'" + value.substr(0, 20) + "' in its data is not a number");
        ++count;
      }
      if (count == 0) continue;
      if (count != values_per_point || ++points > width * height)
        throw bad("its text data does not hold " + std::to_string(width * height) + " points of " +
                  std::to_string(values_per_point) + " values");
    }
    if (points != width * height)
      throw bad("its text data holds " + std::to_string(points) + " points, not " +
                std::to_string(width * height));
  } else {
    throw bad("DATA '" + data + "' is not ascii, binary or binary_compressed");
  }
}

namespace {

/// How far (pixels) a point of an unorganized cloud may project from a pixel centre.
constexpr double kPixelTolerance = 0.05;

/// The pixel `camera` projects `p` to, when it lands within kPixelTolerance of a pixel centre
/// inside the image; -1 otherwise.
long pixelOf(const PinholeCamera& camera, const Vec3& p) {
  double u = 0, v = 0;
  if (!camera.project(p, &u, &v)) return -1;
  const double ur = std::round(u), vr = std::round(v);
  if (std::abs(u - ur) > kPixelTolerance || std::abs(v - vr) > kPixelTolerance) return -1;
  if (ur < 0 || vr < 0 || ur >= camera.width || vr >= camera.height) return -1;
  return static_cast<long>(vr) * camera.width + static_cast<long>(ur);
}

/// How far (pixels) two cameras of an organized cloud may place a ray apart at the image's
/// corners, and a point may lie (median) from its own pixel under the camera fitted to them.
constexpr double kOrganizedTolerance = 0.5;

/// The pinhole camera an organized cloud's points fit: least squares of u = fx x/z + cx and
/// v = fy y/z + cy over its finite points (u, v their pixel), none when no point is finite or
/// the fit has no positive focal lengths; and the median distance (pixels) of the points from
/// their own pixel under it.
struct OrganizedFit {
  std::optional<PinholeCamera> fitted;
  long points = 0;
  double median_residual_px = 0.0;
};

template <class Point>
OrganizedFit fitOrganized(const pcl::PointCloud<Point>& cloud) {
  Eigen::Matrix2d Au = Eigen::Matrix2d::Zero(), Av = Eigen::Matrix2d::Zero();
  Eigen::Vector2d bu = Eigen::Vector2d::Zero(), bv = Eigen::Vector2d::Zero();
  OrganizedFit out;
  const auto finite = [&](size_t i) {
    const Vec3 p(cloud[i].x, cloud[i].y, cloud[i].z);
    return p.allFinite() && p.z() > 0;
  };
  for (size_t i = 0; i < cloud.size(); ++i) {
    if (!finite(i)) continue;
    const double u = static_cast<double>(i % cloud.width), v = static_cast<double>(i / cloud.width);
    const Eigen::Vector2d a(cloud[i].x / cloud[i].z, 1), b(cloud[i].y / cloud[i].z, 1);
    Au += a * a.transpose(), Av += b * b.transpose();
    bu += a * u, bv += b * v;
    ++out.points;
  }
  const Eigen::Vector2d fu = Au.ldlt().solve(bu), fv = Av.ldlt().solve(bv);
  if (out.points == 0 || !fu.allFinite() || !fv.allFinite() || !(fu(0) > 0) || !(fv(0) > 0))
    return out;
  PinholeCamera c;
  c.width = static_cast<int>(cloud.width), c.height = static_cast<int>(cloud.height);
  c.fx = fu(0), c.cx = fu(1), c.fy = fv(0), c.cy = fv(1);
  out.fitted = c;
  std::vector<double> residuals;
  residuals.reserve(out.points);
  for (size_t i = 0; i < cloud.size(); ++i) {
    if (!finite(i)) continue;
    double pu = 0, pv = 0;
    c.project(Vec3(cloud[i].x, cloud[i].y, cloud[i].z), &pu, &pv);
    residuals.push_back(std::max(std::abs(pu - static_cast<double>(i % cloud.width)),
                                 std::abs(pv - static_cast<double>(i / cloud.width))));
  }
  std::nth_element(residuals.begin(), residuals.begin() + residuals.size() / 2, residuals.end());
  out.median_residual_px = residuals[residuals.size() / 2];
  return out;
}

/// The largest distance (pixels) at which `given` places the rays of `fitted`'s image corners.
double cornerOffsetPx(const PinholeCamera& fitted, const PinholeCamera& given) {
  double most = 0.0;
  for (const double u : {0.0, fitted.width - 1.0})
    for (const double v : {0.0, fitted.height - 1.0}) {
      const Vec3 ray = fitted.ray(u, v);
      most = std::max({most, std::abs(given.fx * ray.x() + given.cx - u),
                       std::abs(given.fy * ray.y() + given.cy - v)});
    }
  return most;
}

std::runtime_error noPinhole(const std::string& path) {
  return std::runtime_error(path +
                            ": its points fit no pinhole camera looking along +z with x right "
                            "and y down (another frame, or not a depth image?)");
}

std::string intrinsicsText(const PinholeCamera& c) {
  std::ostringstream out;
  out << "fx " << c.fx << ", fy " << c.fy << ", cx " << c.cx << ", cy " << c.cy;
  return out.str();
}

/// An organized cloud holds x and y beside z: `camera` is refused (std::runtime_error naming the
/// file and the intrinsics the points fit) when it places the rays of the camera fitted to them
/// over kOrganizedTolerance from their pixels, so that wrong intrinsics do not silently scale
/// every object. A cloud with no finite point cannot say.
template <class Point>
void checkOrganizedIntrinsics(const std::string& path, const pcl::PointCloud<Point>& cloud,
                              const PinholeCamera& camera) {
  const OrganizedFit fit = fitOrganized(cloud);
  if (fit.points == 0) return;
  if (!fit.fitted) throw noPinhole(path);
  const double offset = cornerOffsetPx(*fit.fitted, camera);
  if (offset <= kOrganizedTolerance) return;
  std::ostringstream out;
  out << path << ": its points do not fit the camera " << intrinsicsText(camera) << " (rays "
      << offset << " px off at the image's corners); they fit " << intrinsicsText(*fit.fitted)
      << ": other intrinsics?";
  throw std::runtime_error(out.str());
}

/// The camera of an organized cloud: `camera` (at the cloud's size) when its points fit it,
/// else the camera fitted to them; refused when they fit no pinhole camera.
template <class Point>
std::optional<PinholeCamera> organizedCamera(const std::string& path,
                                             const pcl::PointCloud<Point>& cloud,
                                             const PinholeCamera* camera) {
  const OrganizedFit fit = fitOrganized(cloud);
  std::optional<PinholeCamera> sized;
  if (camera) {
    sized = *camera;
    sized->width = static_cast<int>(cloud.width), sized->height = static_cast<int>(cloud.height);
  }
  if (fit.points == 0) return sized;
  if (!fit.fitted || fit.median_residual_px > kOrganizedTolerance) throw noPinhole(path);
  if (sized && cornerOffsetPx(*fit.fitted, *sized) <= kOrganizedTolerance) return sized;
  return fit.fitted;
}

/// The depth image of `cloud` and, for each of its pixels, the cloud point there (-1 none).
template <class Point>
DepthImage depthOf(const std::string& path, const pcl::PointCloud<Point>& cloud,
                   const PinholeCamera* camera, std::vector<long>* point_of_pixel,
                   std::optional<PinholeCamera>* own_camera) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  if (cloud.isOrganized() && cloud.width >= 2 && cloud.height >= 2) {
    if (own_camera) {
      *own_camera = organizedCamera(path, cloud, camera);
    } else if (camera) {
      checkOrganizedIntrinsics(path, cloud, *camera);
    }
    DepthImage depth(cloud.width, cloud.height, nan);
    point_of_pixel->resize(cloud.size());
    for (size_t i = 0; i < cloud.size(); ++i) {
      (*point_of_pixel)[i] = static_cast<long>(i);
      const float z = cloud[i].z;
      if (std::isfinite(z) && z > 0) depth.pixels[i] = z;
    }
    return depth;
  }
  if (!camera)
    throw std::runtime_error(path + " is not an organized cloud (height " +
                             std::to_string(cloud.height) +
                             "); a depth image needs one, or the intrinsics to organize it");
  camera->validate();
  DepthImage depth(camera->width, camera->height, nan);
  point_of_pixel->assign(depth.pixels.size(), -1);
  for (size_t i = 0; i < cloud.size(); ++i) {
    const Vec3 p(cloud[i].x, cloud[i].y, cloud[i].z);
    if (!p.allFinite()) continue;
    const long pixel = pixelOf(*camera, p);
    const std::string where = path + ": point " + std::to_string(i) + " (" + std::to_string(p.x()) +
                              ", " + std::to_string(p.y()) + ", " + std::to_string(p.z()) + ")";
    if (pixel < 0)
      throw std::runtime_error(
          where + " does not fall on a pixel of the " + std::to_string(camera->width) + "x" +
          std::to_string(camera->height) + " camera fx " + std::to_string(camera->fx) + ", fy " +
          std::to_string(camera->fy) + ", cx " + std::to_string(camera->cx) + ", cy " +
          std::to_string(camera->cy) + ": other intrinsics, or an image of another size?");
    if ((*point_of_pixel)[pixel] >= 0)
      throw std::runtime_error(where + " falls on the pixel of point " +
                               std::to_string((*point_of_pixel)[pixel]) +
                               ": not the points of one depth image");
    (*point_of_pixel)[pixel] = static_cast<long>(i);
    if (p.z() > 0) depth.pixels[pixel] = static_cast<float>(p.z());
  }
  return depth;
}

}  // namespace

DepthImage readDepthPcd(const std::string& path, const PinholeCamera* camera,
                        Image<uint32_t>* labels, std::optional<PinholeCamera>* own_camera) {
  checkPcdHeader(path);
  std::vector<long> point_of_pixel;
  if (own_camera) own_camera->reset();
  if (!labels) {
    pcl::PointCloud<pcl::PointXYZ> cloud;
    if (pcl::io::loadPCDFile(path, cloud) != 0)
      throw std::runtime_error("cannot read cloud " + path);
    return depthOf(path, cloud, camera, &point_of_pixel, own_camera);
  }
  const pcl::PointCloud<pcl::PointXYZL> cloud = readLabelledCloud(path);
  DepthImage depth = depthOf(path, cloud, camera, &point_of_pixel, own_camera);
  *labels = Image<uint32_t>(depth.width, depth.height, 0);
  for (size_t i = 0; i < point_of_pixel.size(); ++i)
    if (point_of_pixel[i] >= 0) labels->pixels[i] = cloud[point_of_pixel[i]].label;
  return depth;
}

void writePredictionH5(const std::string& path, const PredictionGrids& g) {
  try {
    H5::H5File file(path, H5F_ACC_TRUNC);
    const hsize_t r = g.grid.resolution;
    const hsize_t dims[3] = {r, r, r};
    H5::DataSpace space(3, dims);
    auto put = [&](const char* name, const Grid3<float>& grid) {
      if (grid.data.size() != r * r * r) return;
      file.createDataSet(name, H5::PredType::NATIVE_FLOAT, space)
          .write(grid.data.data(), H5::PredType::NATIVE_FLOAT);
    };
    put("tsdf", g.tsdf_m);
    put("occupancy_probability", g.occupancy_probability);
    put("partial_tsdf", g.partial_tsdf_m);
    put("partial_weight", g.partial_weight);
    if (g.labels.data.size() == r * r * r)
      file.createDataSet("labels", H5::PredType::NATIVE_INT32, space)
          .write(g.labels.data.data(), H5::PredType::NATIVE_INT);
    H5::Group root = file.openGroup("/");
    const hsize_t three = 3, sixteen = 16;
    root.createAttribute("origin_table", H5::PredType::NATIVE_DOUBLE, H5::DataSpace(1, &three))
        .write(H5::PredType::NATIVE_DOUBLE, g.grid.origin_table.data());
    root.createAttribute("voxel_size_m", H5::PredType::NATIVE_DOUBLE, H5::DataSpace())
        .write(H5::PredType::NATIVE_DOUBLE, &g.grid.voxel_size_m);
    root.createAttribute("resolution", H5::PredType::NATIVE_INT, H5::DataSpace())
        .write(H5::PredType::NATIVE_INT, &g.grid.resolution);
    Eigen::Matrix<double, 4, 4, Eigen::RowMajor> T = g.T_table_camera.matrix();
    root.createAttribute("T_table_camera", H5::PredType::NATIVE_DOUBLE, H5::DataSpace(1, &sixteen))
        .write(H5::PredType::NATIVE_DOUBLE, T.data());
  } catch (const H5::Exception& e) {
    throw std::runtime_error("cannot write " + path + ": " + e.getDetailMsg());
  }
}

}  // namespace simstack
