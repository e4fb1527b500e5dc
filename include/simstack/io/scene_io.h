#pragma once
/// @file scene_io.h
/// Files of a reconstruction: superquadric scenes (YAML), meshes (PLY) and labelled clouds
/// (PCD) through PCL, predicted grids (HDF5). Every function throws std::runtime_error
/// naming the file on failure.

#include <optional>
#include <string>
#include <vector>

#include "simstack/geometry/image.h"
#include "simstack/geometry/pinhole_camera.h"
#include "simstack/geometry/superquadric.h"
#include "simstack/geometry/triangle_mesh.h"
#include "simstack/geometry/voxel_grid.h"
#include "simstack/io/image_io.h"

namespace simstack {

/// `objects:` list of {id, scale [a1,a2,a3], exponents [r,s,t], position [x,y,z],
/// orientation [qw,qx,qy,qz]} in `frame` (the table frame); with `truncated` (one per shape)
/// also each object's `truncated` flag (InstanceEstimate::truncated); with `camera`, the
/// position of the one camera whose depth points the objects were fitted to (`camera: [x, y,
/// z]`, the same frame), where the grasp ranking tests what that camera saw past.
void writeSuperquadricsYaml(const std::string& path, const std::vector<SuperquadricShape>& shapes,
                            const std::string& frame = "table",
                            const std::vector<bool>& truncated = {},
                            const std::optional<Vec3>& camera = std::nullopt);
/// Reads what writeSuperquadricsYaml wrote; `ids` (when given) receives each object's `id`
/// (its index when the file has none), `camera` (when given) the file's camera (std::nullopt
/// when it has none). Throws std::runtime_error naming the file and field.
std::vector<SuperquadricShape> readSuperquadricsYaml(const std::string& path,
                                                     std::vector<int>* ids = nullptr,
                                                     std::optional<Vec3>* camera = nullptr);

void writeMeshPly(const std::string& path, const TriangleMesh& mesh);
TriangleMesh readMeshPly(const std::string& path);

/// PCD of x y z label (pcl::PointXYZL), binary.
void writeLabelledCloudPcd(const std::string& path, const Points3& points,
                           const std::vector<int>& labels);

/// The points of a PCD of x y z label (as writeLabelledCloudPcd writes it) whose label is
/// `label`; the file is checked first (checkPcdHeader). Throws std::runtime_error naming the
/// file when it cannot be read or has no label field.
Points3 readLabelledPoints(const std::string& path, uint32_t label);

/// Reads a PCD file's header and checks it before PCL sees the file (PCL crashes on some
/// malformed files and allocates what any header claims): x y z fields, consistent SIZE /
/// TYPE / COUNT, WIDTH and HEIGHT at most kMaxDepthImageSide, POINTS = WIDTH x HEIGHT, and
/// binary data as long as the header promises. Throws std::runtime_error naming the file.
void checkPcdHeader(const std::string& path);

/// Depth (metres) from a PCD: z of each point, NaN where invalid. An organized cloud gives
/// its own size. An unorganized one (HEIGHT 1, as some datasets store a view with its invalid
/// points dropped) is organized with `camera`: each point goes to the pixel it projects to,
/// which must lie within 0.05 px of a pixel centre of the camera's image, one point a pixel
/// (std::runtime_error naming the file and the first point that does not; also without a
/// camera). An organized cloud given a camera is checked against the camera its points fit
/// (least squares of their pixels): rays placed over half a pixel apart at the image's corners
/// are refused, naming the intrinsics they fit. With `own_camera`, an organized cloud's camera
/// is written there instead: `camera` (at the cloud's size) when its points fit it, else the
/// camera fitted to them, refused when their median distance from their pixel under it is over
/// half a pixel (std::nullopt for an unorganized cloud). With
/// `labels`, also the label of each pixel's point (pcl::PointXYZL; 0 where none); a file
/// without a label field is refused.
DepthImage readDepthPcd(const std::string& path, const PinholeCamera* camera = nullptr,
                        Image<uint32_t>* labels = nullptr,
                        std::optional<PinholeCamera>* own_camera = nullptr);

/// Grids of one prediction, all on `grid`: datasets tsdf, occupancy_probability, labels,
/// partial_tsdf, partial_weight ([z][y][x]), with attributes origin_table, voxel_size_m,
/// resolution and T_table_camera (4x4 row-major).
struct PredictionGrids {
  GridSpec grid;
  Transform T_table_camera = Transform::Identity();
  Grid3<float> tsdf_m, occupancy_probability, partial_tsdf_m, partial_weight;
  Grid3<int> labels;
};
void writePredictionH5(const std::string& path, const PredictionGrids& grids);

}  // namespace simstack
