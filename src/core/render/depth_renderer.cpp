#include "simstack/render/depth_renderer.h"

#include <embree3/rtcore.h>

#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

namespace simstack {

SensorNoiseConfig SensorNoiseConfig::kinect(uint64_t seed) {
  SensorNoiseConfig c;
  c.sigma_base_m = 0.0012;
  c.sigma_quadratic_per_m = 0.0019;
  c.dropout_probability = 0.01;
  c.max_incidence_deg = 80.0;
  c.seed = seed;
  return c;
}

SensorNoiseConfig SensorNoiseConfig::realsense(uint64_t seed) {
  SensorNoiseConfig c;
  // D435 at 1280x720: sigma(z) = z^2 * 0.08 px / (640 px * 0.05 m), 2.5 mm at 1 m, over a
  // 0.5 mm floor; its minimum range at that resolution is 0.28 m.
  c.sigma_base_m = 0.0005;
  c.sigma_stereo_per_m = 0.08 / (640.0 * 0.05);
  c.shadow_baseline_m = 0.05;
  c.min_depth_m = 0.28;
  c.dropout_probability = 0.02;
  c.max_incidence_deg = 75.0;
  c.seed = seed;
  return c;
}

SensorNoiseConfig SensorNoiseConfig::preset(SensorModel model, uint64_t seed) {
  return model == SensorModel::realsense ? realsense(seed) : kinect(seed);
}

SensorModel parseSensorModel(const std::string& name) {
  if (name == "kinect") return SensorModel::kinect;
  if (name == "realsense") return SensorModel::realsense;
  throw std::invalid_argument("sensor model '" + name + "': choose kinect or realsense");
}

const char* sensorModelName(SensorModel model) {
  return model == SensorModel::realsense ? "realsense" : "kinect";
}

struct DepthRenderer::Impl {
  RTCDevice device = nullptr;
  RTCScene scene = nullptr;
  std::vector<int> instance_of_geometry;
  RenderConfig config;

  ~Impl() {
    if (scene) rtcReleaseScene(scene);
    if (device) rtcReleaseDevice(device);
  }

  void addMesh(const TriangleMesh& mesh, int instance) {
    RTCGeometry geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
    auto* vb = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0,
                                                           RTC_FORMAT_FLOAT3, 3 * sizeof(float),
                                                           mesh.vertices.size()));
    auto* ib = static_cast<unsigned*>(
        rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                3 * sizeof(unsigned), mesh.triangles.size()));
    for (size_t i = 0; i < mesh.vertices.size(); ++i) {
      for (int k = 0; k < 3; ++k) vb[3 * i + k] = static_cast<float>(mesh.vertices[i][k]);
    }
    for (size_t i = 0; i < mesh.triangles.size(); ++i) {
      for (int k = 0; k < 3; ++k) ib[3 * i + k] = static_cast<unsigned>(mesh.triangles[i][k]);
    }
    rtcCommitGeometry(geom);
    const unsigned id = rtcAttachGeometry(scene, geom);
    rtcReleaseGeometry(geom);
    if (instance_of_geometry.size() <= id) instance_of_geometry.resize(id + 1, kNoSurface);
    instance_of_geometry[id] = instance;
  }

  // Returns the hit distance in units of `dir` (inf when none).
  float intersect(const Vec3& org, const Vec3& dir, float tfar, int* instance, Vec3f* normal,
                  int* triangle = nullptr) const {
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    RTCRayHit rh;
    rh.ray.org_x = static_cast<float>(org.x());
    rh.ray.org_y = static_cast<float>(org.y());
    rh.ray.org_z = static_cast<float>(org.z());
    rh.ray.dir_x = static_cast<float>(dir.x());
    rh.ray.dir_y = static_cast<float>(dir.y());
    rh.ray.dir_z = static_cast<float>(dir.z());
    rh.ray.tnear = 0.0f;
    rh.ray.tfar = tfar;
    rh.ray.mask = 0xFFFFFFFFu;
    rh.ray.flags = 0;
    rh.ray.time = 0.0f;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(scene, &context, &rh);
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) {
      if (instance) *instance = kNoSurface;
      if (triangle) *triangle = -1;
      return std::numeric_limits<float>::infinity();
    }
    if (triangle) *triangle = static_cast<int>(rh.hit.primID);
    if (instance) *instance = instance_of_geometry[rh.hit.geomID];
    if (normal) *normal = Vec3f(rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z).normalized();
    return rh.ray.tfar;
  }
};

DepthRenderer::DepthRenderer(const Scene& scene, const RenderConfig& config)
    : impl_(std::make_unique<Impl>()) {
  // Instance k + 1 of an 8-bit image: 0 is the table and kNoSurface no hit.
  if (scene.objects.size() >= kNoSurface)
    throw std::invalid_argument("DepthRenderer: " + std::to_string(scene.objects.size()) +
                                " objects; the instance image holds at most " +
                                std::to_string(kNoSurface - 1));
  impl_->config = config;
  impl_->device = rtcNewDevice("threads=1");
  if (!impl_->device)
    throw std::runtime_error("Embree: cannot create a device (error " +
                             std::to_string(rtcGetDeviceError(nullptr)) + ")");
  impl_->scene = rtcNewScene(impl_->device);
  rtcSetSceneBuildQuality(impl_->scene, RTC_BUILD_QUALITY_MEDIUM);
  if (config.with_table) {
    const double h = config.table_half_size_m;
    TriangleMesh table;
    table.vertices = {Vec3(-h, -h, 0), Vec3(h, -h, 0), Vec3(h, h, 0), Vec3(-h, h, 0)};
    table.triangles = {Eigen::Vector3i(0, 1, 2), Eigen::Vector3i(0, 2, 3)};
    impl_->addMesh(table, 0);
  }
  for (size_t k = 0; k < scene.objects.size(); ++k) {
    const auto& o = scene.objects[k];
    impl_->addMesh(o.shape->mesh().transformed(o.T_table_object), static_cast<int>(k + 1));
  }
  rtcCommitScene(impl_->scene);
}

DepthRenderer::DepthRenderer(const TriangleMesh& mesh, double max_range_m)
    : impl_(std::make_unique<Impl>()) {
  impl_->config.with_table = false;
  impl_->config.max_range_m = max_range_m;
  impl_->device = rtcNewDevice("threads=1");
  if (!impl_->device)
    throw std::runtime_error("Embree: cannot create a device (error " +
                             std::to_string(rtcGetDeviceError(nullptr)) + ")");
  impl_->scene = rtcNewScene(impl_->device);
  if (!mesh.empty()) impl_->addMesh(mesh, 1);
  rtcCommitScene(impl_->scene);
}

DepthRenderer::~DepthRenderer() = default;

double DepthRenderer::castRay(const Vec3& origin, const Vec3& direction, int* instance,
                              int* triangle) const {
  const double len = direction.norm();
  const float t =
      impl_->intersect(origin, direction / len, static_cast<float>(impl_->config.max_range_m),
                       instance, nullptr, triangle);
  return t;
}

RenderResult DepthRenderer::render(const PinholeCamera& camera, const Transform& T_table_camera,
                                   const SensorNoiseConfig& noise, bool with_normals) const {
  camera.validate();
  RenderResult out;
  out.depth = DepthImage(camera.width, camera.height, 0.0f);
  out.instances = InstanceImage(camera.width, camera.height, kNoSurface);
  if (with_normals) out.normals_table = Image<Vec3f>(camera.width, camera.height, Vec3f::Zero());
  const Mat3 R = T_table_camera.linear();
  const Vec3 org = T_table_camera.translation();
  const double cos_max = std::cos(noise.max_incidence_deg * M_PI / 180.0);
  const bool noisy = noise.sigma_base_m > 0.0 || noise.sigma_quadratic_per_m > 0.0 ||
                     noise.sigma_stereo_per_m > 0.0 || noise.dropout_probability > 0.0 ||
                     noise.max_incidence_deg < 90.0 || noise.min_depth_m > 0.0;
  // The shadowing eye, in the table frame.
  const Vec3 second_eye = org + R * Vec3(noise.shadow_baseline_m, 0.0, 0.0);
#pragma omp parallel for schedule(dynamic, 8)
  for (int v = 0; v < camera.height; ++v) {
    // One generator per row keeps noise identical for any thread count.
    std::mt19937_64 rng(noise.seed * 1000003ull + static_cast<uint64_t>(v));
    std::normal_distribution<double> gauss(0.0, 1.0);
    std::uniform_real_distribution<double> uni(0.0, 1.0);
    for (int u = 0; u < camera.width; ++u) {
      const Vec3 ray_camera = camera.ray(u, v);  // z = 1, so distance along it is depth
      const Vec3 dir = R * ray_camera;
      int instance = kNoSurface;
      Vec3f n;
      const float t =
          impl_->intersect(org, dir, static_cast<float>(impl_->config.max_range_m), &instance, &n);
      if (!std::isfinite(t)) continue;
      // Orient the normal towards the camera.
      const Vec3f dir_f = dir.cast<float>();
      if (n.dot(dir_f) > 0.0f) n = -n;
      double depth = t;
      if (noisy) {
        const double cos_inc = -n.dot(dir_f.normalized());
        if (cos_inc < cos_max || uni(rng) < noise.dropout_probability || depth < noise.min_depth_m)
          continue;
        const double sigma = noise.sigma_base_m +
                             noise.sigma_quadratic_per_m * (depth - 0.4) * (depth - 0.4) +
                             noise.sigma_stereo_per_m * depth * depth;
        depth += sigma * gauss(rng);
      }
      if (noise.shadow_baseline_m > 0.0) {
        // Lifted off the surface along its normal so the shadow ray does not hit its start.
        const Vec3 hit = org + static_cast<double>(t) * dir + 1e-4 * n.cast<double>();
        const Vec3 to_eye = second_eye - hit;
        const double reach = to_eye.norm();
        if (std::isfinite(
                impl_->intersect(hit, to_eye / reach, static_cast<float>(reach), nullptr, nullptr)))
          continue;
      }
      out.depth.at(u, v) = static_cast<float>(depth);
      out.instances.at(u, v) = static_cast<uint8_t>(instance);
      if (with_normals) out.normals_table.at(u, v) = n;
    }
  }
  return out;
}

}  // namespace simstack
