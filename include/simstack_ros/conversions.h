#pragma once
/// @file conversions.h
/// ROS message <-> core type conversions (free functions, no algorithm). The input conversions
/// throw std::invalid_argument with a message fit for a throttled ROS warning.

#include <geometry_msgs/Pose.h>
#include <geometry_msgs/TransformStamped.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/PointCloud2.h>
#include <shape_msgs/Mesh.h>
#include <simstack/ObjectArray.h>
#include <visualization_msgs/MarkerArray.h>

#include <cstdint>
#include <vector>

#include "simstack/geometry/image.h"
#include "simstack/geometry/pinhole_camera.h"
#include "simstack/geometry/superquadric.h"
#include "simstack/geometry/voxel_grid.h"

namespace simstack {

struct SceneEstimate;

/// Depth in metres from a 16UC1 (mm) or 32FC1 (m) image; 0 and NaN stay missing (0).
/// Rejects other encodings, big-endian data and a step or data size that does not fit.
DepthImage depthFromImage(const sensor_msgs::Image& msg);
/// A workspace mask (mono8 or 8UC1): 0 = ignore the pixel. Throws std::invalid_argument for
/// another encoding, an empty image or one whose data is shorter than its step says.
Image<uint8_t> maskFromImage(const sensor_msgs::Image& msg);

/// A frame name as tf2 takes it: without the leading '/' of tf1's names (older drivers and bags
/// still send "/camera_depth_optical_frame"; tf2 refuses it and warns on every lookup).
std::string tf2Frame(const std::string& frame);

/// tf's transform as a rigid one. tf2 takes quaternions within 1 % of unit length (a transform
/// typed to three places, 0.707) and hands them on as they are: normalised here, so that its
/// rotation is one and what is placed with it stays rigid.
Transform rigidFromTf(const geometry_msgs::TransformStamped& transform);

/// Pinhole intrinsics of the image a CameraInfo describes: the rectified P matrix (K when P is
/// zero), with its ROI cut out and its binning applied (image_geometry's reduced resolution,
/// as image_proc's crop_decimate publishes; the result is then a `window`, whose principal
/// point may lie outside it). Rejects an ROI outside the full image, a full image whose
/// intrinsics PinholeCamera::validate refuses, zero focal lengths and empty sizes.
PinholeCamera cameraFromInfo(const sensor_msgs::CameraInfo& msg);

/// The inverses, as a depth camera publishes: 16UC1 in mm (missing = 0) and its CameraInfo
/// (K and P of `camera`, no distortion).
sensor_msgs::Image depthImageMsg(const std_msgs::Header& header, const DepthImage& depth);
sensor_msgs::CameraInfo cameraInfoMsg(const std_msgs::Header& header, const PinholeCamera& camera);

/// The message of a core superquadric (same frame).
simstack::Superquadric superquadricMsg(const SuperquadricShape& sq);

/// x y z (float32) of `points` (metres) in `header.frame_id`.
sensor_msgs::PointCloud2 pointCloud(const std_msgs::Header& header, const Points3& points);

/// The ids of an estimate's objects (hypothesis 0) as published: `ids[k]` for object k (from an
/// ObjectTracker), or k itself when `ids` is empty. Throws std::invalid_argument when `ids` is
/// neither empty nor one per object.
using ObjectIds = std::vector<uint32_t>;

/// The functions below take an estimate in the table frame and write it in the frame `header`
/// names, `T_frame_table` (the table frame in it; the identity when it is the table frame).

/// The objects of hypothesis 0 of `estimate` and the superquadrics of the further decomposed
/// hypotheses; `views`, `samples` and `symmetries` (the network passes) as the pipeline ran.
/// Each object carries its superquadric as a mesh too.
ObjectArray objectArrayMsg(const std_msgs::Header& header, const SceneEstimate& estimate, int views,
                           int samples, int symmetries, const ObjectIds& ids = {},
                           const Transform& T_frame_table = Transform::Identity());

/// Every object's surface samples: x y z label rgb (label id + 1; rgb packed as rviz reads it,
/// the colour of the object's marker, which follows its id).
sensor_msgs::PointCloud2 instancesCloud(const std_msgs::Header& header,
                                        const SceneEstimate& estimate, const ObjectIds& ids = {},
                                        const Transform& T_frame_table = Transform::Identity());

/// A superquadric as a closed triangle mesh in its own frame (shape_msgs/Mesh, a few hundred
/// triangles): a planning-scene collision object placed at the superquadric's pose.
shape_msgs::Mesh superquadricMesh(const SuperquadricShape& sq);

/// Voxel centres whose occupancy probability is at least `min_probability`: x y z probability.
sensor_msgs::PointCloud2 occupancyCloud(const std_msgs::Header& header,
                                        const Grid3<float>& probability, double min_probability,
                                        const Transform& T_frame_table = Transform::Identity());

/// DELETEALL (the markers of vanished objects go), then per object a triangle mesh of its
/// superquadric (namespace "superquadrics") and a text label with its id ("labels"), marker id
/// = object id, in the colours of instancesCloud().
visualization_msgs::MarkerArray objectMarkers(
    const std_msgs::Header& header, const SceneEstimate& estimate, const ObjectIds& ids = {},
    const Transform& T_frame_table = Transform::Identity());

/// 16UC1 image of pixel labels: 0 none, id + 1 for the pixels of object k (`labels` holds k;
/// -1 is 0; ids above 65534 are written as 65535).
sensor_msgs::Image labelImage(const std_msgs::Header& header, const Image<int>& labels,
                              const ObjectIds& ids = {});

}  // namespace simstack
