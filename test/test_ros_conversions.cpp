#include <gtest/gtest.h>
#include <sensor_msgs/image_encodings.h>
#include <tf2_eigen/tf2_eigen.h>

#include <cmath>
#include <cstring>
#include <limits>

#include "simstack/io/image_io.h"
#include "simstack/pipeline/scene_perception.h"
#include "simstack_ros/conversions.h"
#include "simstack_ros/grasp_conversions.h"
#include "simstack_ros/stamp_pairing.h"

using namespace simstack;

namespace {
sensor_msgs::Image image(const std::string& encoding, int w, int h, int bytes) {
  sensor_msgs::Image m;
  m.encoding = encoding;
  m.width = w;
  m.height = h;
  m.step = w * bytes;
  m.data.assign(static_cast<size_t>(m.step) * h, 0);
  return m;
}
Transform fromPose(const geometry_msgs::Pose& p) {
  Transform T;
  tf2::fromMsg(p, T);
  return T;
}
}  // namespace

TEST(Conversions, Depth16UC1IsMillimetres) {
  auto m = image(sensor_msgs::image_encodings::TYPE_16UC1, 4, 2, 2);
  const uint16_t mm = 1234;
  std::memcpy(&m.data[2 * 5], &mm, 2);  // pixel (1, 1)
  const DepthImage d = depthFromImage(m);
  EXPECT_FLOAT_EQ(d.at(1, 1), 1.234f);
  EXPECT_EQ(d.at(0, 0), 0.0f);
}

TEST(Conversions, Depth32FC1NanBecomesMissing) {
  auto m = image(sensor_msgs::image_encodings::TYPE_32FC1, 2, 1, 4);
  const float vals[2] = {std::numeric_limits<float>::quiet_NaN(), 0.75f};
  std::memcpy(m.data.data(), vals, 8);
  const DepthImage d = depthFromImage(m);
  EXPECT_EQ(d.at(0, 0), 0.0f);
  EXPECT_FLOAT_EQ(d.at(1, 0), 0.75f);
}

TEST(Conversions, BadImagesAreRejectedWithAReason) {
  auto rgb = image(sensor_msgs::image_encodings::RGB8, 4, 4, 3);
  try {
    depthFromImage(rgb);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("rgb8"), std::string::npos);
  }
  auto short_data = image(sensor_msgs::image_encodings::TYPE_16UC1, 4, 4, 2);
  short_data.data.resize(10);
  EXPECT_THROW(depthFromImage(short_data), std::invalid_argument);
  auto empty = image(sensor_msgs::image_encodings::TYPE_16UC1, 0, 0, 2);
  EXPECT_THROW(depthFromImage(empty), std::invalid_argument);
  // Wider than the tools read: refused by its size, before its pixels are read.
  auto wide = image(sensor_msgs::image_encodings::TYPE_16UC1, kMaxDepthImageSide + 1, 2, 2);
  try {
    depthFromImage(wide);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("4097x2, larger than"), std::string::npos) << e.what();
  }
}

TEST(Conversions, MasksAreMono8) {
  auto m = image(sensor_msgs::image_encodings::MONO8, 3, 2, 1);
  m.step = 4;  // padded rows
  m.data.assign(8, 0);
  m.data[4 + 2] = 255;  // pixel (2, 1)
  const Image<uint8_t> mask = maskFromImage(m);
  EXPECT_EQ(mask.width, 3);
  EXPECT_EQ(mask.at(2, 1), 255);
  EXPECT_EQ(mask.at(0, 0), 0);
  try {
    maskFromImage(image(sensor_msgs::image_encodings::TYPE_16UC1, 3, 2, 2));
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("16UC1"), std::string::npos);
  }
  m.data.resize(5);
  EXPECT_THROW(maskFromImage(m), std::invalid_argument);
}

TEST(Conversions, CameraInfo) {
  sensor_msgs::CameraInfo info;
  info.width = 640;
  info.height = 480;
  info.K = {525, 0, 319.5, 0, 525, 239.5, 0, 0, 1};
  const PinholeCamera c = cameraFromInfo(info);
  EXPECT_DOUBLE_EQ(c.fx, 525);
  EXPECT_DOUBLE_EQ(c.cy, 239.5);
  info.K[0] = 0;
  EXPECT_THROW(cameraFromInfo(info), std::invalid_argument);
}

TEST(Conversions, CameraInfoWithRoiAndBinningDescribesThePublishedImage) {
  PinholeCamera full;  // 640x480, fx 525
  std_msgs::Header header;
  sensor_msgs::CameraInfo info = cameraInfoMsg(header, full);
  info.roi.x_offset = 100;
  info.roi.y_offset = 40;
  info.roi.width = 400;
  info.roi.height = 300;
  info.binning_x = info.binning_y = 2;
  const PinholeCamera c = cameraFromInfo(info);
  EXPECT_EQ(c.width, 200);
  EXPECT_EQ(c.height, 150);
  // A point seen at full-resolution pixel (u, v) lies at ((u - x0) / 2, (v - y0) / 2) in the
  // cropped, binned image: the top-left pixel of each bin is the one kept.
  for (const Vec3& p : {Vec3(0.05, -0.02, 0.7), Vec3(-0.1, 0.08, 1.1), Vec3(0.0, 0.0, 0.5)}) {
    const double u = full.fx * p.x() / p.z() + full.cx, v = full.fy * p.y() / p.z() + full.cy;
    EXPECT_NEAR(c.fx * p.x() / p.z() + c.cx, (u - 100) / 2, 1e-9);
    EXPECT_NEAR(c.fy * p.y() / p.z() + c.cy, (v - 40) / 2, 1e-9);
  }
  // As image_proc's crop_decimate publishes a crop: do_rectify set, here with a distortion
  // model. The image is rectified already; the window is the same.
  sensor_msgs::CameraInfo flagged = info;
  flagged.roi.do_rectify = true;
  flagged.distortion_model = "plumb_bob";
  flagged.D = {0.1, -0.05, 0.001, 0.002, 0.0};
  const PinholeCamera f = cameraFromInfo(flagged);
  EXPECT_EQ(f.width, c.width);
  EXPECT_EQ(f.height, c.height);
  EXPECT_DOUBLE_EQ(f.cx, c.cx);
  info.binning_x = info.binning_y = 0;  // 0 and 1 both mean none
  EXPECT_EQ(cameraFromInfo(info).width, 400);
  EXPECT_DOUBLE_EQ(cameraFromInfo(info).cx, full.cx - 100);

  auto refused = [&](sensor_msgs::RegionOfInterest roi, const std::string& words = "ROI") {
    sensor_msgs::CameraInfo bad = info;
    bad.roi = roi;
    try {
      cameraFromInfo(bad);
    } catch (const std::invalid_argument& e) {
      return std::string(e.what()).find(words) != std::string::npos;
    }
    return false;
  };
  sensor_msgs::RegionOfInterest outside = info.roi;
  outside.x_offset = 300;  // 300 + 400 > 640
  EXPECT_TRUE(refused(outside));
  sensor_msgs::RegionOfInterest half = info.roi;
  half.height = 0;
  EXPECT_TRUE(refused(half));
  EXPECT_FALSE(refused(info.roi));
  sensor_msgs::RegionOfInterest offsets_only;
  offsets_only.x_offset = 100;
  EXPECT_TRUE(refused(offsets_only));
  sensor_msgs::CameraInfo binned_away = info;  // binning wider than the window
  binned_away.binning_x = binned_away.binning_y = 4000000000u;
  try {
    cameraFromInfo(binned_away);
    ADD_FAILURE() << "accepted binning of 4e9";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("binning 4000000000x4000000000 is larger than its "),
              std::string::npos)
        << e.what();
  }
  // The top-left corner, without the principal point: a window, its own camera unchecked but
  // for its full image's.
  sensor_msgs::CameraInfo corner = info;
  corner.roi = sensor_msgs::RegionOfInterest();
  corner.roi.width = 200;
  corner.roi.height = 150;
  const PinholeCamera w = cameraFromInfo(corner);
  EXPECT_TRUE(w.window);
  EXPECT_EQ(w.width, 200);
  EXPECT_DOUBLE_EQ(w.cx, full.cx);
  corner.K[0] = corner.P[0] = 0.82;  // normalized intrinsics of the full image
  corner.K[4] = corner.P[5] = 1.09;
  try {
    cameraFromInfo(corner);
    ADD_FAILURE() << "normalized intrinsics accepted through a window";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("field of view"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(cameraFromInfo(cameraInfoMsg(header, full)).window);
}

TEST(Conversions, DepthAndCameraInfoRoundTrip) {
  DepthImage depth(3, 2, 0.0f);
  depth.at(0, 0) = 0.5f;
  depth.at(1, 0) = 1.2344f;  // to the millimetre
  depth.at(2, 1) = std::numeric_limits<float>::quiet_NaN();
  std_msgs::Header header;
  header.frame_id = "cam";
  const sensor_msgs::Image msg = depthImageMsg(header, depth);
  EXPECT_EQ(msg.encoding, sensor_msgs::image_encodings::TYPE_16UC1);
  const DepthImage back = depthFromImage(msg);
  EXPECT_FLOAT_EQ(back.at(0, 0), 0.5f);
  EXPECT_FLOAT_EQ(back.at(1, 0), 1.234f);
  EXPECT_EQ(back.at(2, 1), 0.0f);
  EXPECT_EQ(back.at(1, 1), 0.0f);
  PinholeCamera camera;
  camera.fx = 600;
  camera.cy = 250;
  const PinholeCamera c = cameraFromInfo(cameraInfoMsg(header, camera));
  EXPECT_DOUBLE_EQ(c.fx, 600);
  EXPECT_DOUBLE_EQ(c.cy, 250);
  EXPECT_EQ(c.width, 640);
}

TEST(GraspConversions, RequestNumbersAreTheDecimalsWritten) {
  EXPECT_EQ(asWritten(0.1f), 0.1);
  EXPECT_EQ(asWritten(0.2f), 0.2);
  EXPECT_EQ(asWritten(0.05f), 0.05);
  EXPECT_EQ(asWritten(0.123f), 0.123);
  EXPECT_NE(static_cast<double>(0.1f), 0.1);  // what a plain conversion would rank on
  EXPECT_EQ(asWritten(1e-30f), 1e-30);
  EXPECT_TRUE(std::isnan(asWritten(std::nanf(""))));
  EXPECT_EQ(asWritten(-std::numeric_limits<float>::infinity()),
            -std::numeric_limits<double>::infinity());
  EXPECT_EQ(asWritten(std::numeric_limits<float>::max()), 3.4028235e38);
}

TEST(GraspConversions, ScenesComeFromObjectsThenHypotheses) {
  ObjectArray msg;
  SuperquadricShape sq;
  sq.scale_m = Vec3(0.05, 0.04, 0.03);
  sq.exponents = Vec3(2, 4, 8);
  sq.T_table_object.linear() = Eigen::AngleAxisd(0.3, Vec3::UnitZ()).toRotationMatrix();
  sq.T_table_object.translation() = Vec3(0.1, -0.2, 0.03);
  Object o;
  o.superquadric = superquadricMsg(sq);
  msg.objects.push_back(o);
  SceneSample other;
  other.superquadrics.push_back(superquadricMsg(sq));
  other.superquadrics.push_back(superquadricMsg(sq));
  msg.hypotheses.push_back(other);
  const auto one = graspScenes(msg, 1);
  ASSERT_EQ(one.size(), 1u);
  EXPECT_TRUE(one[0][0].scale_m.isApprox(sq.scale_m));
  EXPECT_TRUE(one[0][0].T_table_object.isApprox(sq.T_table_object, 1e-9));
  const auto three = graspScenes(msg, 3);  // only one further hypothesis exists
  ASSERT_EQ(three.size(), 2u);
  EXPECT_EQ(three[1].size(), 2u);
  // A scene published in another frame carries its table there: the shapes come back in the
  // table frame.
  Transform T_base_table = Transform::Identity();
  T_base_table.linear() = Eigen::AngleAxisd(M_PI / 2, Vec3::UnitX()).toRotationMatrix();
  T_base_table.translation() = Vec3(0.5, 0.0, 0.7);
  ObjectArray in_base = msg;
  in_base.table_in_frame = tf2::toMsg(T_base_table);
  in_base.objects[0].superquadric.pose = tf2::toMsg(T_base_table * sq.T_table_object);
  in_base.hypotheses[0].superquadrics[1].pose = tf2::toMsg(T_base_table * sq.T_table_object);
  const auto back = graspScenes(in_base, 2);
  EXPECT_TRUE(back[0][0].T_table_object.isApprox(sq.T_table_object, 1e-9));
  EXPECT_TRUE(back[1][1].T_table_object.isApprox(sq.T_table_object, 1e-9));
  EXPECT_TRUE(tableInFrame(msg).isApprox(Transform::Identity()));  // all zero: the table's own
  in_base.table_in_frame.orientation.w = 2.0;
  EXPECT_THROW(tableInFrame(in_base), std::invalid_argument);
  msg.objects[0].superquadric.pose.orientation.w = 3.0;
  EXPECT_THROW(graspScenes(msg, 1), std::invalid_argument);
}

// Quaternions typed to a few places (a launch file's static transform, a hand-built request)
// are rotations to the scene's checks once read.
TEST(GraspConversions, QuaternionsTypedToFewPlacesAreRotations) {
  const auto orthonormalError = [](const Transform& T) {
    return (T.linear() * T.linear().transpose() - Eigen::Matrix3d::Identity()).norm();
  };
  const Eigen::Matrix3d quarter = Eigen::AngleAxisd(M_PI / 2, Vec3::UnitZ()).toRotationMatrix();
  Object o;
  o.superquadric.semi_axes.x = o.superquadric.semi_axes.y = o.superquadric.semi_axes.z = 0.05;
  o.superquadric.exponents.x = o.superquadric.exponents.y = o.superquadric.exponents.z = 2.0;
  o.superquadric.pose.position.z = 0.05;
  o.superquadric.pose.orientation.z = o.superquadric.pose.orientation.w = 0.7071;  // norm 0.99999
  const Transform T = rigidFromPose(o.superquadric.pose, "typed");
  EXPECT_LT(orthonormalError(T), 1e-12);
  EXPECT_TRUE(T.linear().isApprox(quarter, 1e-4));
  ObjectArray msg;
  msg.objects.push_back(o);
  EXPECT_EQ(checkScene(graspScenes(msg, 1)[0]), "");
  // A transform tf2 took as typed to three places (norm 0.99985): rigid as looked up.
  geometry_msgs::TransformStamped t;
  t.transform.rotation.z = t.transform.rotation.w = 0.707;
  t.transform.translation.x = 0.2;
  const Transform U = rigidFromTf(t);
  EXPECT_LT(orthonormalError(U), 1e-12);
  EXPECT_TRUE(U.linear().isApprox(quarter, 1e-9));
  EXPECT_EQ(U.translation(), Vec3(0.2, 0, 0));
}

// The camera that measured the objects' points: from table_pose (T_camera_table) when one view
// was fused; none for several views or a pose made by hand (all zero).
TEST(GraspConversions, TheMeasuringCameraIsTheOneViewsCamera) {
  Transform T_table_camera = Transform::Identity();
  T_table_camera.linear() = Eigen::AngleAxisd(2.5, Vec3(1, 0.2, 0).normalized()).toRotationMatrix();
  T_table_camera.translation() = Vec3(0.3, -0.4, 0.9);
  ObjectArray msg;
  msg.views = 1;
  msg.table_pose = tf2::toMsg(T_table_camera.inverse());
  const std::optional<Vec3> camera = measuringCamera(msg);
  ASSERT_TRUE(camera.has_value());
  EXPECT_TRUE(camera->isApprox(T_table_camera.translation(), 1e-9));
  msg.views = 2;
  EXPECT_FALSE(measuringCamera(msg).has_value());
  ObjectArray by_hand;
  by_hand.views = 1;
  EXPECT_FALSE(measuringCamera(by_hand).has_value());
  // A pose that is set but malformed is refused (the service's BAD_SCENE), not passed over:
  // without the camera the test for grasps into an opening the camera saw would be skipped.
  msg.views = 1;
  msg.table_pose.orientation.x = std::nan("");
  EXPECT_THROW(measuringCamera(msg), std::invalid_argument);
  msg.table_pose.orientation = geometry_msgs::Quaternion();
  EXPECT_THROW(measuringCamera(msg), std::invalid_argument);  // a zero quaternion, a position
}

TEST(GraspConversions, ToolPoseLooksIntoTheSurfaceInTheAskedFrameAndArrowsShowTheOutcome) {
  RankedGrasp g;
  g.candidate.contact_table = Vec3(0.1, 0.2, 0.3);
  g.candidate.approach_table = Vec3(1, 0, 0);
  std_msgs::Header base;
  base.frame_id = "base_link";
  Transform T_base_table = Transform::Identity();
  T_base_table.translation() = Vec3(0.5, 0.0, 0.7);
  Transform T_base_turned = T_base_table;  // the table turned in the poses' frame
  T_base_turned.linear() = Eigen::AngleAxisd(M_PI / 2, Vec3::UnitZ()).toRotationMatrix();
  const Grasp turned = graspMsg(g, base, T_base_turned, 0.05);
  EXPECT_NEAR(turned.approach.y, 1.0, 1e-9);  // the approach in the poses' frame, as the tool's
  const Transform Tz = fromPose(turned.tool_pose.pose);
  EXPECT_TRUE((Tz.linear() * Vec3::UnitZ())
                  .isApprox(-Vec3(turned.approach.x, turned.approach.y, turned.approach.z), 1e-9));
  const Grasp m = graspMsg(g, base, T_base_table, 0.05);
  EXPECT_NEAR(m.approach.x, 1.0, 1e-9);
  EXPECT_EQ(m.tool_pose.header.frame_id, "base_link");
  EXPECT_EQ(m.pregrasp_pose.header.frame_id, "base_link");
  const Transform T = fromPose(m.tool_pose.pose);
  EXPECT_TRUE((T.linear() * Vec3::UnitZ()).isApprox(-Vec3::UnitX(), 1e-9));  // into the surface
  EXPECT_TRUE(T.translation().isApprox(Vec3(0.6, 0.2, 1.0)));
  const Transform P = fromPose(m.pregrasp_pose.pose);
  EXPECT_TRUE(P.translation().isApprox(Vec3(0.65, 0.2, 1.0), 1e-9));
  EXPECT_FALSE(m.held);  // no pull simulated
  PullOutcome ok;
  g.outcomes = {ok};
  g.freed_share = 1.0;
  RankedGrasp held = g, failed = g;
  held.freed_share = 0.5;
  failed.failed_share = 0.5;
  EXPECT_TRUE(graspMsg(g, base, T_base_table, 0.05).held);
  EXPECT_TRUE(graspMsg(g, base, T_base_table, 0.05).freed);
  EXPECT_FALSE(graspMsg(held, base, T_base_table, 0.05).freed);
  std_msgs::Header h;
  const auto markers = graspMarkers(h, {g, held, failed, failed}, T_base_table);
  const geometry_msgs::Point& tip = markers.markers[1].points[1];  // at the contact, in h's frame
  EXPECT_NEAR(tip.x, 0.6, 1e-9);
  EXPECT_NEAR(tip.z, 1.0, 1e-9);
  ASSERT_EQ(markers.markers.size(), 8u);  // clear, four arrows, three ranks
  const auto colour = [&](int k) {
    const auto& c = markers.markers[k].color;
    return std::vector<float>{c.r, c.g, c.b};
  };
  EXPECT_EQ(colour(1), (std::vector<float>{0, 1, 0}));  // held and freed: green
  EXPECT_EQ(colour(3), (std::vector<float>{1, 1, 0}));  // held, not freed: yellow
  EXPECT_EQ(colour(5), (std::vector<float>{1, 0, 0}));  // failed: red
}

TEST(Conversions, OutputsAreWrittenInTheFrameTheTableIsPlacedIn) {
  SceneEstimate est;
  est.hypotheses.resize(1);
  InstanceEstimate box;
  box.superquadric.scale_m = Vec3(0.05, 0.04, 0.03);
  box.superquadric.exponents = Vec3(8, 8, 8);
  box.superquadric.T_table_object.translation() = Vec3(0.1, 0.0, 0.03);
  box.points = {Vec3(0.1, 0.0, 0.06), Vec3(0.1, 0.0, 0.0)};
  box.measured_points = 1;  // the first point was measured, the second predicted
  // Every point measured on it: the fitter's one and one it was not given.
  box.measured = {Vec3(0.1, 0.0, 0.06), Vec3(0.11, 0.0, 0.06)};
  est.hypotheses[0].instances.push_back(box);
  est.hypotheses[0].decomposed = true;
  est.occupancy_probability = Grid3<float>(GridSpec::sceneGrid(Vec2::Zero(), 0.64, 4), 0.0f);
  est.occupancy_probability.data[0] = 1.0f;        // voxel (0, 0, 0), centre (-0.24, -0.24, 0.08)
  Transform T_base_table = Transform::Identity();  // the table half a turn about z, 0.7 m up
  T_base_table.linear() = Eigen::AngleAxisd(M_PI, Vec3::UnitZ()).toRotationMatrix();
  T_base_table.translation() = Vec3(0.5, 0.0, 0.7);
  std_msgs::Header base;
  base.frame_id = "base_link";
  const ObjectArray msg = objectArrayMsg(base, est, 1, 1, 4, {7}, T_base_table);
  ASSERT_EQ(msg.objects.size(), 1u);
  EXPECT_TRUE(fromPose(msg.table_in_frame).isApprox(T_base_table, 1e-9));
  const geometry_msgs::Point& c = msg.objects[0].superquadric.pose.position;
  EXPECT_NEAR(c.x, 0.4, 1e-9);
  EXPECT_NEAR(c.z, 0.73, 1e-9);
  // The grasp service reads it back in the table frame.
  EXPECT_TRUE(
      graspScenes(msg, 1)[0][0].T_table_object.isApprox(box.superquadric.T_table_object, 1e-6));
  // The grasp service reads the measured points back, in the table frame.
  const Points3 measured = measuredSurface(msg.objects[0], T_base_table.inverse());
  ASSERT_EQ(measured.size(), 2u);
  EXPECT_TRUE(measured[0].isApprox(Vec3(0.1, 0.0, 0.06), 1e-6));
  EXPECT_TRUE(measured[1].isApprox(Vec3(0.11, 0.0, 0.06), 1e-6));
  // The surface: the measured points, then the fitter's samples of the unseen part.
  const sensor_msgs::PointCloud2 surface = msg.objects[0].surface;
  ASSERT_EQ(surface.width * surface.height, 3u);
  float last[3];
  std::memcpy(last, surface.data.data() + 2 * surface.point_step, sizeof(last));
  EXPECT_NEAR(last[2], 0.7f, 1e-6);
  float xyz[3];
  std::memcpy(xyz, surface.data.data(), sizeof(xyz));
  EXPECT_NEAR(xyz[0], 0.4f, 1e-6);
  EXPECT_NEAR(xyz[2], 0.76f, 1e-6);
  const sensor_msgs::PointCloud2 occupied =
      occupancyCloud(base, est.occupancy_probability, 0.5, T_base_table);
  ASSERT_EQ(occupied.width, 1u);
  std::memcpy(xyz, occupied.data.data(), sizeof(xyz));
  const Vec3 centre = T_base_table * est.occupancy_probability.spec.voxelCentre(0, 0, 0);
  EXPECT_NEAR(xyz[0], centre.x(), 1e-6);
  EXPECT_NEAR(xyz[2], centre.z(), 1e-6);
  const auto markers = objectMarkers(base, est, {7}, T_base_table);
  ASSERT_EQ(markers.markers.size(), 3u);  // clear, mesh, label
  EXPECT_NEAR(markers.markers[1].pose.position.x, 0.4, 1e-9);
  EXPECT_NEAR(markers.markers[2].pose.position.z, 0.73 + 0.05 + 0.03, 1e-9);  // above it
}

// A hand-built Object whose surface cloud does not hold what measured_points says, or whose
// fields do not fit its point_step, is refused rather than read out of bounds.
TEST(Conversions, CloudsOfNoPointKeepTheirFields) {
  // An empty table, or an occupancy threshold above every voxel: a valid cloud of 0 points.
  std_msgs::Header header;
  header.frame_id = "table";
  const sensor_msgs::PointCloud2 none = pointCloud(header, {});
  EXPECT_EQ(none.width, 0u);
  EXPECT_EQ(none.height, 1u);
  EXPECT_EQ(none.point_step, 12u);
  ASSERT_EQ(none.fields.size(), 3u);
  EXPECT_TRUE(none.data.empty());
  const Grid3<float> probability(GridSpec::sceneGrid(Vec2(0, 0), 0.32, 8), 0.2f);
  const sensor_msgs::PointCloud2 free =
      occupancyCloud(header, probability, 0.5, Transform::Identity());
  EXPECT_EQ(free.width, 0u);
  EXPECT_EQ(free.fields.size(), 4u);
  EXPECT_EQ(free.row_step, 0u);
  const sensor_msgs::PointCloud2 one = pointCloud(header, {Vec3(1, 2, 3)});
  ASSERT_EQ(one.data.size(), 12u);
  float xyz[3];
  std::memcpy(xyz, one.data.data(), 12);
  EXPECT_EQ(Vec3(xyz[0], xyz[1], xyz[2]), Vec3(1, 2, 3));
}

TEST(Conversions, MalformedSurfaceCloudsAreRefused) {
  Object object;
  object.id = 3;
  object.measured_points = 2;
  sensor_msgs::PointCloud2& cloud = object.surface;
  cloud.width = 2;
  cloud.height = 1;
  for (const char* name : {"x", "y", "z"}) {
    sensor_msgs::PointField f;
    f.name = name;
    f.offset = static_cast<uint32_t>(4 * cloud.fields.size());
    f.datatype = sensor_msgs::PointField::FLOAT32;
    f.count = 1;
    cloud.fields.push_back(f);
  }
  const Transform I = Transform::Identity();
  // Each fault named: the point step, the data's size, the count measured_points claims.
  const auto refusal = [&]() -> std::string {
    try {
      measuredSurface(object, I);
    } catch (const std::invalid_argument& e) {
      return e.what();
    }
    return "accepted";
  };
  EXPECT_NE(refusal().find("point_step 0"), std::string::npos) << refusal();
  cloud.point_step = 12;
  EXPECT_NE(refusal().find("its data holds 0"), std::string::npos) << refusal();
  cloud.data.assign(24, 0);
  object.measured_points = 3;
  EXPECT_NE(refusal().find("fewer than the 3 measured_points"), std::string::npos) << refusal();
  object.measured_points = 2;
  cloud.data.clear();
  cloud.data.assign(24, 0);
  EXPECT_EQ(measuredSurface(object, I).size(), 2u);  // two points at the origin
  cloud.point_step = 8;                              // z beyond the point
  cloud.data.assign(16, 0);
  EXPECT_THROW(measuredSurface(object, I), std::invalid_argument);
  // A size whose width x height x point_step passes 2^64 (wrapping to 0) is refused too.
  cloud.width = cloud.height = 1u << 31;
  cloud.point_step = 16;
  object.measured_points = 4000000000u;
  EXPECT_THROW(measuredSurface(object, I), std::invalid_argument);
  cloud.width = 2, cloud.height = 1, object.measured_points = 2;
  cloud.point_step = 12;
  cloud.data.assign(24, 0);
  cloud.fields[1].datatype = sensor_msgs::PointField::FLOAT64;
  EXPECT_THROW(measuredSurface(object, I), std::invalid_argument);
  cloud.fields.pop_back();  // no z
  cloud.fields[1].datatype = sensor_msgs::PointField::FLOAT32;
  EXPECT_THROW(measuredSurface(object, I), std::invalid_argument);
  object.measured_points = 0;  // nothing measured: nothing read
  EXPECT_TRUE(measuredSurface(object, I).empty());
}

// Images (first) and camera_info (second) as strings naming their stamps.
using Pairing = StampPairing<std::string, std::string>;

TEST(StampPairing, PairsEqualStampsInEitherOrderAndToleratesLag) {
  Pairing pairing(4);
  EXPECT_FALSE(pairing.addFirst(1, "image 1"));
  auto pair = pairing.addSecond(1, "info 1");
  ASSERT_TRUE(pair);
  EXPECT_EQ(pair->first, "image 1");
  EXPECT_EQ(pair->second, "info 1");
  EXPECT_FALSE(pairing.addSecond(2, "info 2"));
  pair = pairing.addFirst(2, "image 2");
  ASSERT_TRUE(pair);
  EXPECT_EQ(pair->second, "info 2");
  // camera_info three frames behind its images: every image still finds its own.
  for (int t = 3; t <= 5; ++t) EXPECT_FALSE(pairing.addFirst(t, "image " + std::to_string(t)));
  for (int t = 3; t <= 5; ++t) {
    pair = pairing.addSecond(t, "info " + std::to_string(t));
    ASSERT_TRUE(pair) << t;
    EXPECT_EQ(pair->first, "image " + std::to_string(t));
  }
  EXPECT_EQ(pairing.forgotten(), 0);
  EXPECT_EQ(pairing.pendingFirst() + pairing.pendingSecond(), 0u);
}

TEST(StampPairing, AHalfPairIsForgottenOnceALaterPairCompletes) {
  Pairing pairing(4);
  EXPECT_FALSE(pairing.addSecond(1, "info 1"));  // its image was lost
  EXPECT_FALSE(pairing.addFirst(2, "image 2"));  // nor was its info sent yet
  EXPECT_FALSE(pairing.addFirst(3, "image 3"));
  ASSERT_TRUE(pairing.addSecond(3, "info 3"));
  // info 1 and image 2 came before image 3: no partner can follow them in stamp order.
  EXPECT_EQ(pairing.forgotten(), 2);
  EXPECT_EQ(pairing.pendingFirst() + pairing.pendingSecond(), 0u);
}

TEST(StampPairing, HalfPairsStampedAheadDoNotHoldBackTheFramesAfterThem) {
  // A bag played in a loop, back at its start: the end of the last pass left two camera_info
  // and an image without partners, stamped later than every frame of the next pass.
  // message_filters' ExactTime forgets the oldest stamp first and would keep them for ever.
  Pairing pairing(2);
  EXPECT_FALSE(pairing.addSecond(100, "info 100"));
  EXPECT_FALSE(pairing.addSecond(101, "info 101"));
  EXPECT_FALSE(pairing.addFirst(102, "image 102"));
  auto pair = pairing.addSecond(1, "info 1");
  EXPECT_FALSE(pair);
  pair = pairing.addFirst(1, "image 1");
  ASSERT_TRUE(pair) << "the first frame of the new pass was held back";
  EXPECT_EQ(pair->second, "info 1");
  EXPECT_EQ(pairing.pendingFirst() + pairing.pendingSecond(), 0u);
  EXPECT_EQ(pairing.forgotten(), 3);
  // More half pairs ahead than are kept: the oldest arrivals go first, and new ones pair.
  for (int t = 200; t < 210; ++t) pairing.addSecond(t, "info");
  EXPECT_EQ(pairing.pendingSecond(), 2u);
  EXPECT_FALSE(pairing.addFirst(2, "image 2"));
  EXPECT_TRUE(pairing.addSecond(2, "info 2"));
}
