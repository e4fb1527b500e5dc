// rostest (test/ros/perception.test): the perception node on synthetic depth frames of known
// scenes. Every frame carries its own stamp, so an output is matched to the frame it answers.
#include <diagnostic_msgs/DiagnosticArray.h>
#include <dynamic_reconfigure/Reconfigure.h>
#include <gtest/gtest.h>
#include <octomap/OcTree.h>
#include <ros/ros.h>
#include <rosgraph_msgs/Log.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/image_encodings.h>
#include <simstack/ObjectArray.h>
#include <simstack/SaveOctomap.h>
#include <std_msgs/Bool.h>
#include <std_srvs/Empty.h>
#include <tf2_eigen/tf2_eigen.h>
#include <tf2_ros/static_transform_broadcaster.h>
#include <tf2_ros/transform_broadcaster.h>
#include <tf2_ros/transform_listener.h>
#include <visualization_msgs/MarkerArray.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "../test_scenes.h"
#include "simstack/render/depth_renderer.h"
#include "simstack/scene/scene.h"
#include "simstack_ros/conversions.h"

namespace simstack {
namespace {

const char* kCameraFrame = "camera_depth_optical_frame";

SuperquadricShape box(const Vec3& half, const Vec3& centre, double yaw) {
  SuperquadricShape sq;
  sq.scale_m = half;
  sq.exponents = Vec3::Constant(12.0);
  sq.T_table_object = Transform::Identity();
  sq.T_table_object.linear() = Eigen::AngleAxisd(yaw, Vec3::UnitZ()).toRotationMatrix();
  sq.T_table_object.translation() = centre;
  return sq;
}

/// Two boxes resting apart on the table, seen from above at an angle.
std::vector<SuperquadricShape> knownPile() {
  return {box(Vec3(0.06, 0.04, 0.05), Vec3(0.02, -0.08, 0.05), 0.3),
          box(Vec3(0.05, 0.05, 0.04), Vec3(0.0, 0.09, 0.04), -0.2)};
}

/// Each object of `truth` has an object of `out` whose centre is within 2 cm of its own.
void expectEachFound(const ObjectArray& out, const std::vector<SuperquadricShape>& truth) {
  for (const SuperquadricShape& t : truth) {
    double nearest = 1e9;
    for (const Object& o : out.objects) {
      const auto& p = o.superquadric.pose.position;
      nearest = std::min(nearest, (Vec3(p.x, p.y, p.z) - t.T_table_object.translation()).norm());
    }
    EXPECT_LT(nearest, 0.02) << "no object centre within 2 cm of "
                             << t.T_table_object.translation().transpose();
  }
}

/// The test's topics and tf, advertised and subscribed once for the whole program: a topic
/// unadvertised at the end of one test and advertised again by the next leaves the nodes to
/// reconnect to it, and a node whose old connection has not dropped when the new
/// advertisement reaches it may never reconnect, so that the next frame is lost. One static
/// broadcaster holds every camera frame sent (a second one's message would replace its own).
struct Wire {
  Wire() {
    image_pub = nh.advertise<sensor_msgs::Image>("/camera/depth/image_rect", 1, true);
    info_pub = nh.advertise<sensor_msgs::CameraInfo>("/camera/depth/camera_info", 1, true);
    objects_sub = nh.subscribe<ObjectArray>("/camera/perception/objects", 10,
                                            [this](const ObjectArray::ConstPtr& msg) {
                                              std::lock_guard<std::mutex> lock(mutex);
                                              received.push_back(*msg);
                                            });
    markers_sub = nh.subscribe<visualization_msgs::MarkerArray>(
        "/camera/perception/markers", 10,
        [this](const visualization_msgs::MarkerArray::ConstPtr& msg) {
          std::lock_guard<std::mutex> lock(mutex);
          markers[msg->markers.empty() ? ros::Time() : msg->markers.front().header.stamp] = *msg;
        });
    estimated_sub = nh.subscribe<ObjectArray>("/estimating/perception/objects", 10,
                                              [this](const ObjectArray::ConstPtr& msg) {
                                                std::lock_guard<std::mutex> lock(mutex);
                                                estimated.push_back(*msg);
                                              });
  }
  /// Whether both perception nodes fed by the camera topics listen to them and publish to
  /// the test.
  bool connected() const {
    return objects_sub.getNumPublishers() > 0 && markers_sub.getNumPublishers() > 0 &&
           estimated_sub.getNumPublishers() > 0 && image_pub.getNumSubscribers() >= 2 &&
           info_pub.getNumSubscribers() >= 2;
  }

  ros::NodeHandle nh;
  ros::Publisher image_pub, info_pub;
  ros::Subscriber objects_sub, markers_sub, estimated_sub;
  tf2_ros::StaticTransformBroadcaster tf;
  std::mutex mutex;
  std::vector<ObjectArray> received, estimated;
  std::map<ros::Time, visualization_msgs::MarkerArray> markers;
};
std::unique_ptr<Wire> wire;  // made by the first test, dropped by main before ROS shuts down

class PerceptionNodeTest : public ::testing::Test {
 protected:
  void SetUp() override {
    T_table_camera_ = lookAt(Vec3(0.45, -0.3, 0.55), Vec3(0.0, 0.0, 0.04));
    if (!wire) {
      wire = std::make_unique<Wire>();
      geometry_msgs::TransformStamped t = tf2::eigenToTransform(T_table_camera_);
      t.header.stamp = ros::Time::now();
      t.header.frame_id = "table";
      t.child_frame_id = kCameraFrame;
      wire->tf.sendTransform(t);
    }
    ASSERT_TRUE(ros::service::waitForService("/camera/perception/save_octomap", 60000))
        << "the perception node did not come up";
    // An answer published before a subscription is connected would be lost.
    for (int i = 0; i < 1200 && !wire->connected(); ++i) {  // 120 s: three nodes warm up
      ros::spinOnce();
      ros::WallDuration(0.1).sleep();
    }
    ASSERT_TRUE(wire->connected()) << "the perception nodes are not connected to the test";
  }

  /// The depth of `shapes` (metres), as the node's camera sees them.
  DepthImage render(const std::vector<SuperquadricShape>& shapes) const {
    const DepthRenderer renderer(Scene::fromSuperquadrics(shapes));
    return renderer.render(camera_, T_table_camera_).depth;
  }

  std_msgs::Header header(ros::Time stamp) const {
    std_msgs::Header h;
    h.stamp = stamp;
    h.frame_id = kCameraFrame;
    return h;
  }
  sensor_msgs::Image imageMsg(const DepthImage& depth, ros::Time stamp) const {
    return depthImageMsg(header(stamp), depth);
  }
  sensor_msgs::CameraInfo infoMsg(ros::Time stamp) const {
    return cameraInfoMsg(header(stamp), camera_);
  }

  /// Publishes a frame under a fresh stamp and waits up to `seconds` for the objects that
  /// answer it (std::nullopt when none came).
  std::optional<ObjectArray> send(sensor_msgs::Image image, sensor_msgs::CameraInfo info,
                                  double seconds = 30.0) {
    const ros::Time stamp = ros::Time::now();
    image.header.stamp = info.header.stamp = stamp;
    wire->info_pub.publish(info);
    wire->image_pub.publish(image);
    return answerTo(wire->received, stamp, seconds);
  }
  std::optional<ObjectArray> sendDepth(const DepthImage& depth, double seconds = 30.0) {
    return send(imageMsg(depth, ros::Time(0)), infoMsg(ros::Time(0)), seconds);
  }

  /// The estimating node's answer to the frame of `stamp`, waiting up to `seconds`.
  std::optional<ObjectArray> estimatedFor(ros::Time stamp, double seconds) {
    return answerTo(wire->estimated, stamp, seconds);
  }
  /// The message of `answers` (filled by a callback under the wire's mutex) stamped `stamp`,
  /// waiting up to `seconds` for it.
  std::optional<ObjectArray> answerTo(const std::vector<ObjectArray>& answers, ros::Time stamp,
                                      double seconds) {
    const ros::WallTime until = ros::WallTime::now() + ros::WallDuration(seconds);
    while (ros::ok() && ros::WallTime::now() < until) {
      ros::spinOnce();
      {
        std::lock_guard<std::mutex> lock(wire->mutex);
        for (const ObjectArray& o : answers)
          if (o.header.stamp == stamp) return o;
      }
      ros::WallDuration(0.02).sleep();
    }
    return std::nullopt;
  }
  ros::NodeHandle nh_;
  PinholeCamera camera_;
  Transform T_table_camera_;
};

TEST_F(PerceptionNodeTest, AKnownPileGivesItsObjects) {
  const std::vector<SuperquadricShape> truth = knownPile();
  const std::optional<ObjectArray> out = sendDepth(render(truth), 60.0);
  ASSERT_TRUE(out) << "no objects within 60 s";
  EXPECT_EQ(out->header.frame_id, "table");
  EXPECT_FALSE(out->table_estimated);
  EXPECT_EQ(out->samples, 3u);
  EXPECT_EQ(out->symmetries, 4u);  // config/perception.yaml's
  EXPECT_GT(out->total_ms, 0.0f);
  ASSERT_EQ(out->objects.size(), truth.size());
  expectEachFound(*out, truth);
  for (const Object& o : out->objects) {
    EXPECT_GT(o.surface.width, 0u);
    EXPECT_GT(o.voxels, 0u);
    EXPECT_GT(o.visible_fraction, 0.05f);
    EXPECT_LT(o.visible_fraction, 0.95f);
  }
}

TEST_F(PerceptionNodeTest, IdsStayWithTheirObjectsAndLateSubscribersGetTheLatchedOutputs) {
  const std::vector<SuperquadricShape> truth = knownPile();
  const std::optional<ObjectArray> first = sendDepth(render(truth), 60.0);
  const std::optional<ObjectArray> second = sendDepth(render(truth), 60.0);
  ASSERT_TRUE(first && second) << "no objects within 60 s";
  ASSERT_EQ(first->objects.size(), truth.size());
  ASSERT_EQ(second->objects.size(), truth.size());
  // Each object of the second frame has the id of the first frame's object where it stands.
  for (const Object& b : second->objects) {
    const auto& q = b.superquadric.pose.position;
    const Object* nearest = nullptr;
    double best = 1e9;
    for (const Object& a : first->objects) {
      const auto& p = a.superquadric.pose.position;
      const double d = std::hypot(p.x - q.x, p.y - q.y, p.z - q.z);
      if (d < best) best = d, nearest = &a;
    }
    ASSERT_NE(nearest, nullptr);
    EXPECT_LT(best, 0.01);
    EXPECT_EQ(b.id, nearest->id);
    // The superquadric as a mesh for a planning scene: closed, indices in range.
    EXPECT_GT(b.mesh.triangles.size(), 100u);
    EXPECT_LT(b.mesh.triangles.size(), 1000u);
    for (const shape_msgs::MeshTriangle& t : b.mesh.triangles)
      for (uint32_t v : t.vertex_indices) ASSERT_LT(v, b.mesh.vertices.size());
  }
  // A subscriber that comes after the frame still gets it: the outputs are latched.
  std::optional<visualization_msgs::MarkerArray> late_markers;
  std::optional<sensor_msgs::PointCloud2> late_instances;
  std::optional<bool> ready;
  std::optional<sensor_msgs::Image> late_labels;
  ros::Subscriber l = nh_.subscribe<sensor_msgs::Image>(
      "/camera/perception/labels", 1,
      [&](const sensor_msgs::Image::ConstPtr& msg) { late_labels = *msg; });
  ros::Subscriber m = nh_.subscribe<visualization_msgs::MarkerArray>(
      "/camera/perception/markers", 1,
      [&](const visualization_msgs::MarkerArray::ConstPtr& msg) { late_markers = *msg; });
  ros::Subscriber i = nh_.subscribe<sensor_msgs::PointCloud2>(
      "/camera/perception/instances", 1,
      [&](const sensor_msgs::PointCloud2::ConstPtr& msg) { late_instances = *msg; });
  ros::Subscriber r = nh_.subscribe<std_msgs::Bool>(
      "/camera/perception/ready", 1,
      [&](const std_msgs::Bool::ConstPtr& msg) { ready = msg->data; });
  for (int k = 0; k < 200 && !(late_markers && late_instances && ready && late_labels); ++k) {
    ros::spinOnce();
    ros::WallDuration(0.05).sleep();
  }
  ASSERT_TRUE(late_markers && late_instances && ready) << "no latched markers, instances or ready";
  EXPECT_TRUE(*ready);
  EXPECT_EQ(late_instances->header.stamp, second->header.stamp);
  ASSERT_TRUE(late_labels) << "no latched labels";
  EXPECT_EQ(late_labels->header.stamp, second->header.stamp) << "the latched labels are older";
  ASSERT_FALSE(late_markers->markers.empty());
  EXPECT_EQ(late_markers->markers.front().action, visualization_msgs::Marker::DELETEALL);
  std::set<int> marker_ids;
  for (const auto& marker : late_markers->markers)
    if (marker.ns == "superquadrics") marker_ids.insert(marker.id);
  std::set<int> object_ids;
  for (const Object& o : second->objects) object_ids.insert(static_cast<int>(o.id));
  EXPECT_EQ(marker_ids, object_ids);
}

TEST_F(PerceptionNodeTest, ACroppedBinnedImageIsReadThroughItsCameraInfo) {
  // What image_proc's crop_decimate publishes: the pile's part of the image, every second
  // pixel of every second row, and the full camera's info with its ROI and binning.
  const std::vector<SuperquadricShape> truth = knownPile();
  const DepthImage full = render(truth), table = render({});
  const test::PixelBox box = test::pilePixels(full, table, 40);
  ASSERT_LE(box.u0, box.u1) << "the pile is not in view";
  // Even offsets and an even size (the bins' pixels), the last row and column excluded.
  const int u0 = box.u0 & ~1, v0 = box.v0 & ~1, u1 = (box.u1 + 1) & ~1, v1 = (box.v1 + 1) & ~1;
  DepthImage binned((u1 - u0) / 2, (v1 - v0) / 2, 0.0f);
  for (int v = 0; v < binned.height; ++v)
    for (int u = 0; u < binned.width; ++u) binned.at(u, v) = full.at(u0 + 2 * u, v0 + 2 * v);
  sensor_msgs::CameraInfo info = infoMsg(ros::Time(0));
  info.binning_x = info.binning_y = 2;
  info.roi.x_offset = u0, info.roi.y_offset = v0;
  info.roi.width = u1 - u0, info.roi.height = v1 - v0;
  ASSERT_LT(binned.width * binned.height, full.width * full.height / 5);

  const std::optional<ObjectArray> out = send(imageMsg(binned, ros::Time(0)), info, 60.0);
  ASSERT_TRUE(out) << "no objects within 60 s";
  ASSERT_EQ(out->objects.size(), truth.size());
  expectEachFound(*out, truth);
}

TEST_F(PerceptionNodeTest, ATf1FrameNameIsTf2s) {
  // Older drivers and bags name frames with a leading '/', which tf2 refuses.
  sensor_msgs::Image image = imageMsg(render(knownPile()), ros::Time(0));
  sensor_msgs::CameraInfo info = infoMsg(ros::Time(0));
  image.header.frame_id = info.header.frame_id = std::string("/") + kCameraFrame;
  const std::optional<ObjectArray> out = send(image, info, 60.0);
  ASSERT_TRUE(out) << "no objects within 60 s";
  EXPECT_EQ(out->header.frame_id, "table");
  EXPECT_EQ(out->objects.size(), knownPile().size());
}

TEST_F(PerceptionNodeTest, BadInputIsSkippedAndTheNodeKeepsPublishing) {
  const DepthImage depth = render(knownPile());
  const sensor_msgs::CameraInfo info = infoMsg(ros::Time(0));
  std::vector<
      std::pair<std::string, std::function<void(sensor_msgs::Image*, sensor_msgs::CameraInfo*)>>>
      cases = {
          {"rgb8", [](sensor_msgs::Image* i, sensor_msgs::CameraInfo*) { i->encoding = "rgb8"; }},
          {"8UC1", [](sensor_msgs::Image* i, sensor_msgs::CameraInfo*) { i->encoding = "8UC1"; }},
          {"big-endian",
           [](sensor_msgs::Image* i, sensor_msgs::CameraInfo*) { i->is_bigendian = 1; }},
          {"size differs from camera_info",
           [](sensor_msgs::Image*, sensor_msgs::CameraInfo* c) { c->width = 320; }},
          {"all zero",
           [](sensor_msgs::Image* i, sensor_msgs::CameraInfo*) {
             std::fill(i->data.begin(), i->data.end(), 0);
           }},
          {"all NaN (32FC1)",
           [](sensor_msgs::Image* i, sensor_msgs::CameraInfo*) {
             i->encoding = "32FC1";
             i->step = 4 * i->width;
             i->data.assign(size_t(i->step) * i->height, 0);
             const float nan = std::nanf("");
             for (size_t k = 0; k < size_t(i->width) * i->height; ++k)
               std::memcpy(i->data.data() + 4 * k, &nan, 4);
           }},
          {"ROI outside the full image",
           [](sensor_msgs::Image*, sensor_msgs::CameraInfo* c) {
             c->roi.x_offset = 600, c->roi.width = 100, c->roi.height = 100;
           }},
          {"zero focal length",
           [](sensor_msgs::Image*, sensor_msgs::CameraInfo* c) { c->K[0] = c->P[0] = 0; }},
          {"normalized intrinsics",
           [](sensor_msgs::Image*, sensor_msgs::CameraInfo* c) {
             c->K[0] = c->P[0] = 0.82, c->K[4] = c->P[5] = 1.09;
             c->K[2] = c->P[2] = 0.5, c->K[5] = c->P[6] = 0.5;
           }},
          {"principal point outside the image",
           [](sensor_msgs::Image*, sensor_msgs::CameraInfo* c) { c->K[2] = c->P[2] = 1999.5; }},
          {"depth beyond the sensor's range (32FC1)",
           [](sensor_msgs::Image* i, sensor_msgs::CameraInfo*) {
             i->encoding = "32FC1";
             i->step = 4 * i->width;
             i->data.assign(size_t(i->step) * i->height, 0);
             const float far = 1e30f;
             for (size_t k = 0; k < size_t(i->width) * i->height; ++k)
               std::memcpy(i->data.data() + 4 * k, &far, 4);
           }},
          {"no frame_id",
           [](sensor_msgs::Image* i, sensor_msgs::CameraInfo* c) {
             i->header.frame_id = c->header.frame_id = "";
           }},
          {"no tf for the frame",
           [](sensor_msgs::Image* i, sensor_msgs::CameraInfo* c) {
             i->header.frame_id = c->header.frame_id = "nowhere";
           }},
      };
  // A frame stamped 0 (no capture time) is skipped: tf would place it now, and its scene would
  // never be stale.
  wire->info_pub.publish(infoMsg(ros::Time(0)));
  wire->image_pub.publish(imageMsg(depth, ros::Time(0)));
  EXPECT_FALSE(answerTo(wire->received, ros::Time(0), 2.0)) << "published for a frame stamped 0";
  const ros::Time first_bad = ros::Time::now();
  for (auto& [name, spoil] : cases) {
    sensor_msgs::Image image = imageMsg(depth, ros::Time(0));
    sensor_msgs::CameraInfo bad_info = info;
    spoil(&image, &bad_info);
    EXPECT_FALSE(send(image, bad_info, 2.0)) << name << ": published for a bad frame";
  }
  // The last case's reason, as /diagnostics reports it: tf2's text once, not once per attempt
  // of the 0.5 s wait, and the way to give the node its table.
  std::string last_error;
  ros::Subscriber diagnostics = nh_.subscribe<diagnostic_msgs::DiagnosticArray>(
      "/diagnostics", 10, [&](const diagnostic_msgs::DiagnosticArray::ConstPtr& msg) {
        for (const auto& status : msg->status)
          if (status.name == "camera/perception: perception")
            for (const auto& kv : status.values)
              if (kv.key == "last error") last_error = kv.value;
      });
  for (int i = 0; i < 300 && last_error.find("nowhere") == std::string::npos; ++i) {
    ros::spinOnce();
    ros::WallDuration(0.02).sleep();
  }
  EXPECT_NE(last_error.find("no transform table <- 'nowhere' within 0.5 s"), std::string::npos)
      << last_error;
  EXPECT_LT(last_error.size(), 600u) << last_error;
  EXPECT_NE(last_error.find("~estimate_table"), std::string::npos) << last_error;
  const std::optional<ObjectArray> good = sendDepth(depth, 60.0);
  ASSERT_TRUE(good) << "the node stopped publishing after bad input";
  // Frames are perceived in order: an answer to a bad frame later than its 2 s would have come
  // before the good frame's.
  std::lock_guard<std::mutex> lock(wire->mutex);
  for (const ObjectArray& o : wire->received)
    EXPECT_FALSE(o.header.stamp >= first_bad && o.header.stamp < good->header.stamp)
        << "published for a bad frame (stamp " << o.header.stamp << ")";
}

TEST_F(PerceptionNodeTest, AnEmptyTableGivesAnEmptyScene) {
  const std::optional<ObjectArray> out = sendDepth(render({}), 60.0);
  ASSERT_TRUE(out);
  EXPECT_TRUE(out->objects.empty());
  // The markers follow the objects on a topic of their own.
  const ros::WallTime until = ros::WallTime::now() + ros::WallDuration(10.0);
  for (bool got = false; !got && ros::WallTime::now() < until;) {
    ros::spinOnce();
    std::lock_guard<std::mutex> lock(wire->mutex);
    got = wire->markers.count(out->header.stamp) > 0;
    if (!got) ros::WallDuration(0.02).sleep();
  }
  std::lock_guard<std::mutex> lock(wire->mutex);
  ASSERT_TRUE(wire->markers.count(out->header.stamp)) << "no markers for the empty scene";
  const auto& markers = wire->markers.at(out->header.stamp).markers;
  ASSERT_EQ(markers.size(), 1u);
  EXPECT_EQ(markers[0].action, visualization_msgs::Marker::DELETEALL);
}

TEST_F(PerceptionNodeTest, ResetAndSaveOctomap) {
  const std::optional<ObjectArray> before = sendDepth(render(knownPile()), 60.0);
  ASSERT_TRUE(before);
  ASSERT_FALSE(before->objects.empty());
  std_srvs::Empty empty;
  EXPECT_TRUE(ros::service::call("/camera/perception/reset", empty));
  // The tracker forgot its objects: the same pile again gets ids never given before.
  const std::optional<ObjectArray> after = sendDepth(render(knownPile()), 60.0);
  ASSERT_TRUE(after);
  ASSERT_FALSE(after->objects.empty());
  for (const auto& o : after->objects)
    for (const auto& p : before->objects) EXPECT_NE(o.id, p.id) << "an id kept over the reset";
  // A reset while a frame is perceived (the worker takes the frame at once and needs over
  // 100 ms for it): that frame is not published with the ids the reset forgot; it is dropped,
  // or, had the worker not begun it yet, perceived after the reset with new ids.
  const ros::Time during = ros::Time::now();
  wire->info_pub.publish(infoMsg(during));
  wire->image_pub.publish(imageMsg(render(knownPile()), during));
  ros::WallDuration(0.05).sleep();
  EXPECT_TRUE(ros::service::call("/camera/perception/reset", empty));
  if (const std::optional<ObjectArray> overtaken = answerTo(wire->received, during, 10.0)) {
    for (const auto& o : overtaken->objects)
      for (const auto& p : after->objects) {
        EXPECT_NE(o.id, p.id) << "a frame begun before the reset kept an id the reset forgot";
      }
  }
  const std::optional<ObjectArray> next = sendDepth(render(knownPile()), 60.0);
  ASSERT_TRUE(next) << "no frame answered after a reset during a frame";
  for (const auto& o : next->objects)
    for (const auto& p : after->objects) EXPECT_NE(o.id, p.id) << "an id kept over the reset";
  std::string dir;
  ASSERT_TRUE(nh_.getParam("/camera/perception/output_dir", dir));
  SaveOctomap save;
  for (const char* bad :
       {"../escape.ot", "/tmp/absolute.ot", "sub/dir.ot", "", "scene.txt", ".."}) {
    save.request.file_name = bad;
    ASSERT_TRUE(ros::service::call("/camera/perception/save_octomap", save));
    EXPECT_FALSE(save.response.success) << bad;
    EXPECT_FALSE(save.response.message.empty());
  }
  // A name holding a newline, and one over the file system's 255 bytes: refused by a plain
  // message naming the limit.
  save.request.file_name = "two\nlines.ot";
  ASSERT_TRUE(ros::service::call("/camera/perception/save_octomap", save));
  EXPECT_FALSE(save.response.success);
  EXPECT_NE(save.response.message.find("control character"), std::string::npos)
      << save.response.message;
  save.request.file_name = std::string(300, 'a') + ".ot";
  ASSERT_TRUE(ros::service::call("/camera/perception/save_octomap", save));
  EXPECT_FALSE(save.response.success);
  EXPECT_NE(save.response.message.find("at most 255"), std::string::npos) << save.response.message;
  std::filesystem::create_directories(dir);
  std::filesystem::remove(std::filesystem::path(dir) / "link.ot");
  const std::filesystem::path link_target = test::tempPath("simstack_link_target.ot");
  std::filesystem::remove(link_target);
  std::filesystem::create_symlink(link_target, std::filesystem::path(dir) / "link.ot");
  save.request.file_name = "link.ot";
  ASSERT_TRUE(ros::service::call("/camera/perception/save_octomap", save));
  EXPECT_FALSE(save.response.success) << "wrote through a symbolic link";
  EXPECT_FALSE(std::filesystem::exists(link_target));
  for (const char* name : {"scene.ot", "scene.ot", "scene.bt"}) {  // the second replaces the first
    save.request.file_name = name;
    ASSERT_TRUE(ros::service::call("/camera/perception/save_octomap", save));
    ASSERT_TRUE(save.response.success) << save.response.message;
    EXPECT_EQ(save.response.path, (std::filesystem::path(dir) / name).string());
    // The map's frame is the table's, whatever the outputs' frame.
    std::string table_frame;
    ASSERT_TRUE(nh_.getParam("/camera/perception/table_frame", table_frame));
    EXPECT_EQ(save.response.header.frame_id, table_frame);
    EXPECT_FALSE(save.response.header.stamp.isZero());
  }
  std::unique_ptr<octomap::AbstractOcTree> read(
      octomap::AbstractOcTree::read((std::filesystem::path(dir) / "scene.ot").string()));
  ASSERT_TRUE(read);
  auto* tree = dynamic_cast<octomap::OcTree*>(read.get());
  ASSERT_TRUE(tree);
  size_t occupied = 0;
  for (auto it = tree->begin_leafs(); it != tree->end_leafs(); ++it)
    occupied += tree->isNodeOccupied(*it);
  EXPECT_GT(occupied, 10u);
  octomap::OcTree binary(0.1);
  ASSERT_TRUE(binary.readBinary((std::filesystem::path(dir) / "scene.bt").string()));
  EXPECT_GT(binary.getNumLeafNodes(), 0u);
}

TEST_F(PerceptionNodeTest, LiveSettingsChangeTheNextFrame) {
  const DepthImage depth = render(knownPile());
  auto set = [&](const char* name, int value) {
    dynamic_reconfigure::Reconfigure srv;
    dynamic_reconfigure::IntParameter p;
    p.name = name;
    p.value = value;
    srv.request.config.ints.push_back(p);
    return ros::service::call("/camera/perception/set_parameters", srv);
  };
  ASSERT_TRUE(set("samples", 1));
  ASSERT_TRUE(set("symmetries", 1));
  std::optional<ObjectArray> out = sendDepth(depth, 60.0);
  ASSERT_TRUE(out);
  EXPECT_EQ(out->samples, 1u);
  EXPECT_EQ(out->symmetries, 1u);
  // One name per setting: the parameter the node was started with is the one changed.
  int symmetries = 0;
  ASSERT_TRUE(nh_.getParam("/camera/perception/symmetries", symmetries));
  EXPECT_EQ(symmetries, 1);
  std::vector<std::string> names;
  ASSERT_TRUE(ros::param::getParamNames(names));
  for (const std::string& n : names) {
    EXPECT_NE(n.rfind("/camera/perception/perception/", 0), 0u) << n;
    EXPECT_NE(n.rfind("/camera/perception/node/", 0), 0u) << n;
  }
  // The Hough voting's live settings on ~hough, under the names of the config's hough section.
  dynamic_reconfigure::Reconfigure hough;
  dynamic_reconfigure::DoubleParameter bandwidth;
  bandwidth.name = "bandwidth_m";
  bandwidth.value = 0.04;
  hough.request.config.doubles.push_back(bandwidth);
  ASSERT_TRUE(ros::service::call("/camera/perception/hough/set_parameters", hough));
  double set_bandwidth = 0.0;
  ASSERT_TRUE(nh_.getParam("/camera/perception/hough/bandwidth_m", set_bandwidth));
  EXPECT_DOUBLE_EQ(set_bandwidth, 0.04);
  EXPECT_TRUE(sendDepth(depth, 60.0));  // a frame perceived with it
  // dynamic_reconfigure's range clamp lets NaN through: refused, the value in effect shown.
  dynamic_reconfigure::Reconfigure occupancy;
  dynamic_reconfigure::DoubleParameter occupancy_min;
  occupancy_min.name = "occupancy_min";
  occupancy_min.value = std::nan("");
  occupancy.request.config.doubles.push_back(occupancy_min);
  ASSERT_TRUE(ros::service::call("/camera/perception/set_parameters", occupancy));
  double set_occupancy = 0.0;
  ASSERT_TRUE(nh_.getParam("/camera/perception/occupancy_min", set_occupancy));
  EXPECT_TRUE(set_occupancy > 0.0 && set_occupancy <= 1.0) << set_occupancy;
  // A count of passes the pipeline refuses leaves the one in effect, shown back at once.
  ASSERT_TRUE(set("symmetries", 3));
  ASSERT_TRUE(nh_.getParam("/camera/perception/symmetries", symmetries));
  EXPECT_EQ(symmetries, 1) << "a refused setting is shown back before the next frame";
  out = sendDepth(depth, 60.0);
  ASSERT_TRUE(out);
  EXPECT_EQ(out->symmetries, 1u);
  ASSERT_TRUE(set("samples", 3));
  ASSERT_TRUE(set("symmetries", 4));
  out = sendDepth(depth, 60.0);
  ASSERT_TRUE(out);
  EXPECT_EQ(out->samples, 3u);
  EXPECT_EQ(out->symmetries, 4u);
}

TEST_F(PerceptionNodeTest, AnEstimatedTableIsUsedBroadcastAndRefusedWhenThereIsNone) {
  // Every warning about another broadcaster of the estimated table, from the start: the node
  // must not warn about its own broadcasts.
  std::mutex said_mutex;
  std::vector<std::string> said;
  ros::Subscriber rosout = nh_.subscribe<rosgraph_msgs::Log>(
      "/rosout", 100, [&](const rosgraph_msgs::Log::ConstPtr& log) {
        if (log->msg.find("broadcasts 'table_estimated' under") == std::string::npos) return;
        std::lock_guard<std::mutex> lock(said_mutex);
        said.push_back(log->msg);
      });
  const auto saidUnder = [&](const std::string& parent) {
    std::lock_guard<std::mutex> lock(said_mutex);
    return std::any_of(said.begin(), said.end(), [&](const std::string& m) {
      return m.find("under '" + parent + "'") != std::string::npos;
    });
  };
  tf2_ros::Buffer buffer;
  tf2_ros::TransformListener listener(buffer);
  ros::WallDuration(1.0).sleep();  // the listener connects before the frame is sent
  std::optional<ObjectArray> out = sendDepth(render(knownPile()), 60.0);
  ASSERT_TRUE(out);
  const std::optional<ObjectArray> est = estimatedFor(out->header.stamp, 60.0);
  ASSERT_TRUE(est) << "the estimating node published nothing";
  EXPECT_TRUE(est->table_estimated);
  EXPECT_EQ(est->header.frame_id, "table_estimated");
  EXPECT_EQ(est->objects.size(), knownPile().size());
  EXPECT_TRUE(
      buffer.canTransform("table_estimated", kCameraFrame, est->header.stamp, ros::Duration(5.0)))
      << "the estimated table is not on tf";
  // Depth with no plane in it (random distances): no table, so nothing published for it.
  DepthImage noise(camera_.width, camera_.height, 0.0f);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> range(0.5f, 1.5f);
  for (float& d : noise.pixels) d = range(rng);
  out = sendDepth(noise, 30.0);
  ASSERT_TRUE(out);  // the tf node has a table for it
  EXPECT_FALSE(estimatedFor(out->header.stamp, 5.0)) << "published a frame without a table";
  out = sendDepth(render(knownPile()), 60.0);
  ASSERT_TRUE(out);
  EXPECT_TRUE(estimatedFor(out->header.stamp, 60.0))
      << "stopped publishing after a tableless frame";
  {
    std::lock_guard<std::mutex> lock(said_mutex);
    EXPECT_TRUE(said.empty()) << "warned about its own broadcast: " << said.front();
  }
  // Another node's parent for the estimated table, on /tf and then latched on /tf_static: the
  // node says tf has two parents, naming each.
  const auto tableUnder = [](const std::string& parent) {
    geometry_msgs::TransformStamped t;
    t.header.stamp = ros::Time::now();
    t.header.frame_id = parent;
    t.child_frame_id = "table_estimated";
    t.transform.rotation.w = 1.0;
    return t;
  };
  tf2_ros::TransformBroadcaster other;
  for (int i = 0; i < 40 && !saidUnder("world"); ++i) {
    other.sendTransform(tableUnder("world"));
    sendDepth(render(knownPile()), 5.0);
  }
  EXPECT_TRUE(saidUnder("world")) << "no warning about a second parent on /tf";
  tf2_ros::StaticTransformBroadcaster fixed;
  fixed.sendTransform(tableUnder("urdf_table_parent"));
  for (int i = 0; i < 40 && !saidUnder("urdf_table_parent"); ++i)
    sendDepth(render(knownPile()), 5.0);
  EXPECT_TRUE(saidUnder("urdf_table_parent")) << "no warning about a second parent on /tf_static";
}

TEST_F(PerceptionNodeTest, PosedViewsAccumulateUntilReset) {
  // Three cameras around the pile, each on tf; the accumulating node's own topics.
  ros::Publisher image = nh_.advertise<sensor_msgs::Image>("/accumulating/depth/image_rect", 1);
  ros::Publisher info =
      nh_.advertise<sensor_msgs::CameraInfo>("/accumulating/depth/camera_info", 1);
  std::vector<ObjectArray> answers;
  ros::Subscriber sub = nh_.subscribe<ObjectArray>("/accumulating/perception/objects", 10,
                                                   [&](const ObjectArray::ConstPtr& msg) {
                                                     std::lock_guard<std::mutex> lock(wire->mutex);
                                                     answers.push_back(*msg);
                                                   });
  std::vector<geometry_msgs::TransformStamped> cameras;
  std::vector<Transform> poses;
  for (int k = 0; k < 5; ++k) {
    const double a = 2.0 * M_PI * k / 4 + 0.3;
    // Camera 4 is below the table: the pipeline refuses its views.
    poses.push_back(
        lookAt(Vec3(0.6 * std::cos(a), 0.6 * std::sin(a), k < 4 ? 0.55 : -0.4), Vec3(0, 0, 0.04)));
    geometry_msgs::TransformStamped t = tf2::eigenToTransform(poses.back());
    t.header.stamp = ros::Time::now();
    t.header.frame_id = "table";
    t.child_frame_id = "accumulating_camera_" + std::to_string(k);
    cameras.push_back(t);
  }
  wire->tf.sendTransform(cameras);
  for (int i = 0; i < 300 && (sub.getNumPublishers() == 0 || image.getNumSubscribers() == 0 ||
                              info.getNumSubscribers() == 0);
       ++i)
    ros::WallDuration(0.1).sleep();
  ros::WallDuration(0.5).sleep();
  const DepthRenderer renderer(Scene::fromSuperquadrics(knownPile()));
  // The views fused for the frame of camera k (0 when no answer came within `wait_s`).
  auto send = [&](int k, double age_s = 0.0, double wait_s = 60.0) -> unsigned {
    const ros::Time stamp = ros::Time::now() - ros::Duration(age_s);
    sensor_msgs::Image img = imageMsg(renderer.render(camera_, poses[k]).depth, stamp);
    sensor_msgs::CameraInfo ci = infoMsg(stamp);
    img.header.frame_id = ci.header.frame_id = cameras[k].child_frame_id;
    info.publish(ci);
    image.publish(img);
    const std::optional<ObjectArray> out = answerTo(answers, stamp, wait_s);
    return out ? out->views : 0u;
  };
  EXPECT_EQ(send(0), 1u);
  EXPECT_EQ(send(1), 2u);
  EXPECT_EQ(send(2), 3u);
  EXPECT_EQ(send(3), 3u) << "max_views is 3";
  std_srvs::Empty empty;
  ASSERT_TRUE(ros::service::call("/accumulating/perception/reset", empty));
  EXPECT_EQ(send(0), 1u) << "~reset did not clear the views";
  EXPECT_EQ(send(1), 2u);
  // A refused view is not kept: the next frame fuses with the two good ones.
  EXPECT_EQ(send(4, 0.0, 5.0), 0u) << "a camera below the table was perceived";
  EXPECT_EQ(send(2), 3u) << "a refused view stayed among the accumulated ones";
  // A frame stamped before the last one (a bag that restarted): perceived alone, the views of
  // the other run cleared, and later frames fuse with it again.
  EXPECT_EQ(send(2, 30.0), 1u) << "a frame from the past was fused with newer views";
  EXPECT_EQ(send(3), 2u);
  // Half pairs stamped later than every frame to come (a looped bag gone back to its start,
  // its last camera_info and an image without partners): the next frames still pair and are
  // perceived.
  for (int k = 0; k < 3; ++k) {
    const ros::Time ahead = ros::Time::now() + ros::Duration(100.0 + k);
    sensor_msgs::CameraInfo half_info = infoMsg(ahead);
    sensor_msgs::Image half_image = imageMsg(renderer.render(camera_, poses[0]).depth, ahead);
    half_info.header.frame_id = half_image.header.frame_id = cameras[0].child_frame_id;
    if (k < 2)
      info.publish(half_info);
    else
      image.publish(half_image);
    ros::WallDuration(0.1).sleep();
  }
  ros::WallDuration(0.3).sleep();
  EXPECT_EQ(send(1), 3u) << "a half pair stamped later held back the frames after it";
  // Images whose camera_info is stamped 1 ms later never make a frame: once input_timeout_s
  // (5 s) has passed, the node says why, not that the camera is silent.
  std::string summary;
  ros::Subscriber diagnostics = nh_.subscribe<diagnostic_msgs::DiagnosticArray>(
      "/diagnostics", 10, [&](const diagnostic_msgs::DiagnosticArray::ConstPtr& msg) {
        for (const auto& status : msg->status)
          if (status.name == "accumulating/perception: perception") summary = status.message;
      });
  const ros::WallTime until = ros::WallTime::now() + ros::WallDuration(20.0);
  while (ros::WallTime::now() < until &&
         summary.find("their stamps never match") == std::string::npos) {
    const ros::Time stamp = ros::Time::now();
    sensor_msgs::Image img = imageMsg(renderer.render(camera_, poses[0]).depth, stamp);
    sensor_msgs::CameraInfo ci = infoMsg(stamp + ros::Duration(0.001));
    img.header.frame_id = ci.header.frame_id = cameras[0].child_frame_id;
    info.publish(ci);
    image.publish(img);
    for (int i = 0; i < 10; ++i, ros::WallDuration(0.025).sleep()) ros::spinOnce();
  }
  EXPECT_NE(summary.find("depth images and camera_info arrive but their stamps never match"),
            std::string::npos)
      << summary;
}

TEST_F(PerceptionNodeTest, DiagnosticsComeOncePerDiagnosticPeriod) {
  // Statuses named after the node's namespace, without the leading slash; the accumulating
  // node's ~diagnostic_period is 0.25 s, the camera node's the default 1 s. The period is read
  // from the messages' stamps (set as the node publishes), so that a late delivery to this
  // test on a loaded machine does not count as a missing status.
  std::map<std::string, std::vector<double>> stamps;
  std::map<std::string, std::string> hardware;
  std::mutex mutex;
  ros::Subscriber sub = nh_.subscribe<diagnostic_msgs::DiagnosticArray>(
      "/diagnostics", 100, [&](const diagnostic_msgs::DiagnosticArray::ConstPtr& msg) {
        std::lock_guard<std::mutex> lock(mutex);
        for (const auto& s : msg->status) {
          stamps[s.name].push_back(msg->header.stamp.toSec());
          hardware[s.name] = s.hardware_id;
        }
      });
  for (int i = 0; i < 100 && sub.getNumPublishers() < 3; ++i) ros::WallDuration(0.1).sleep();
  const ros::WallTime until = ros::WallTime::now() + ros::WallDuration(8.0);
  while (ros::WallTime::now() < until) {
    ros::spinOnce();
    ros::WallDuration(0.02).sleep();
  }
  std::lock_guard<std::mutex> lock(mutex);
  // The median gap between consecutive stamps (-1 with fewer than 4 statuses).
  const auto medianGap = [&](const std::string& name) {
    std::vector<double> t = stamps[name];
    if (t.size() < 4) return -1.0;
    std::sort(t.begin(), t.end());
    std::vector<double> gaps;
    for (size_t i = 1; i < t.size(); ++i) gaps.push_back(t[i] - t[i - 1]);
    std::nth_element(gaps.begin(), gaps.begin() + gaps.size() / 2, gaps.end());
    return gaps[gaps.size() / 2];
  };
  const std::string fast = "accumulating/perception: perception",
                    slow = "camera/perception: perception";
  ASSERT_TRUE(stamps.count(fast)) << "no status named '" << fast << "'";
  ASSERT_TRUE(stamps.count(slow)) << "no status named '" << slow << "'";
  EXPECT_NEAR(medianGap(fast), 0.25, 0.05) << stamps[fast].size() << " statuses in 8 s";
  EXPECT_NEAR(medianGap(slow), 1.0, 0.2) << stamps[slow].size() << " statuses in 8 s";
  EXPECT_EQ(hardware[slow], "simstack_perception /camera/perception");
}

TEST_F(PerceptionNodeTest, ATfClockThatJumpedBackIsNoticedAndTheBufferCleared) {
  // A camera whose pose comes on /tf stamped by a clock an hour ahead, then corrected: tf keeps
  // the hour-ahead poses and drops the corrected ones as too old, so without a clear every
  // later frame would be skipped. The node clears its buffer after three such frames.
  tf2_ros::TransformBroadcaster moving;
  const std::string frame = "clock_jump_camera";
  const DepthImage depth = render(knownPile());
  auto sendAt = [&](ros::Time stamp, double seconds) -> bool {
    geometry_msgs::TransformStamped t = tf2::eigenToTransform(T_table_camera_);
    t.header.frame_id = "table";
    t.child_frame_id = frame;
    sensor_msgs::Image image = imageMsg(depth, stamp);
    sensor_msgs::CameraInfo info = infoMsg(stamp);
    image.header.frame_id = info.header.frame_id = frame;
    for (double dt : {-0.2, -0.1, 0.0, 0.1, 0.2}) {  // tf around the stamp, as a driver streams it
      t.header.stamp = stamp + ros::Duration(dt);
      moving.sendTransform(t);
      ros::WallDuration(0.05).sleep();
    }
    wire->info_pub.publish(info);
    wire->image_pub.publish(image);
    return answerTo(wire->received, stamp, seconds).has_value();
  };
  ros::WallDuration(1.0).sleep();  // the nodes' tf listeners connect to the new broadcaster
  const ros::Time ahead = ros::Time::now() + ros::Duration(3600.0);
  ASSERT_TRUE(sendAt(ahead, 60.0)) << "the frame an hour ahead, with its tf, was not perceived";
  // The first of the corrected frames answered; each is waited for 5 s, and a slow answer
  // (a loaded machine) to an earlier one still counts as that frame's.
  std::vector<ros::Time> sent;
  auto firstAnswered = [&]() {
    std::lock_guard<std::mutex> lock(wire->mutex);
    for (size_t k = 0; k < sent.size(); ++k)
      for (const ObjectArray& o : wire->received)
        if (o.header.stamp == sent[k]) return static_cast<int>(k);
    return -1;
  };
  int perceived_at = -1;
  for (int k = 0; k < 8 && perceived_at < 0; ++k) {
    sent.push_back(ros::Time::now());
    sendAt(sent.back(), 5.0);
    perceived_at = firstAnswered();
  }
  const ros::WallTime until = ros::WallTime::now() + ros::WallDuration(60.0);
  while (perceived_at < 0 && ros::WallTime::now() < until) {
    ros::spinOnce();
    ros::WallDuration(0.05).sleep();
    perceived_at = firstAnswered();
  }
  ASSERT_GE(perceived_at, 0) << "no frame perceived after the clock was set back";
  EXPECT_LE(perceived_at, 4) << "the buffer should be cleared after three frames";
}

}  // namespace
}  // namespace simstack

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "test_perception_node");
  ros::NodeHandle nh;
  const int failed = RUN_ALL_TESTS();
  simstack::wire.reset();
  return failed;
}
