#pragma once
/// @file dataset.h
/// The HDF5 scene dataset of docs/design.md section 5. Arrays have the scene index first and grids
/// in C order [z][y][x] (x fastest), so h5py and torch read them as [N, D, H, W]:
///   tsdf        float32 [N, R, R, R]     metres, +-truncation_m
///   votes       float32 [N, 3, R, R, R]  unit vectors (x, y, z channels) to object centroids
///   labels      uint8   [N, R, R, R]     0 free, k object k
///   grid_origin float64 [N, 3]           minimum corner of each scene grid, table frame
///   num_objects int32   [N]
///   objects     float64 [N, K, 15]       see kObjectColumns; unused rows are zero
/// File attributes: resolution, extent_m, voxel_size_m, truncation_m, seed, generator_version,
/// min_objects, max_objects, mesh_names (comma-separated catalogue, empty for superquadrics).

#include <cstdint>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "simstack/offline/dataset/ground_truth.h"
#include "simstack/scene/scene.h"

namespace simstack {

/// Column names of the `objects` array.
extern const char* const kObjectColumns;
/// Written into every file; bump when the format or the generator's output changes.
extern const char* const kGeneratorVersion;

struct DatasetInfo {
  int num_scenes = 0;
  int resolution = 32;
  double extent_m = 0.64;
  double truncation_m = 0.06;
  int max_objects_per_scene = 4;  ///< K, the second dimension of `objects`
  uint64_t seed = 0;
  int min_objects = 3;
  int max_objects = 4;
  std::string generator_version;
  std::vector<std::string> mesh_names;  ///< catalogue of mesh shapes (empty: superquadrics)
};

/// One scene as stored.
struct SceneRecord {
  Scene scene;
  GridSpec grid;
  GroundTruthGrids ground_truth;
};

/// Writes scenes in any order into preallocated arrays. Not thread-safe.
class DatasetWriter {
 public:
  /// Creates (truncates) `path`. Throws std::runtime_error naming the file on failure.
  DatasetWriter(const std::string& path, const DatasetInfo& info);
  ~DatasetWriter();
  void write(int index, const Scene& scene, const GroundTruthGrids& ground_truth);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Throws std::runtime_error naming the first of `paths` whose piles the published figures are
/// measured on (generated with seed 777-780 or 4242-4246, docs/results.md), saying to `use`
/// ("train on") piles of another seed or to pass --allow-held-out. Reads the seed alone; a
/// file that is no dataset is left to DatasetReader.
void refuseHeldOutDatasets(const std::vector<std::string>& paths, const std::string& use);

/// Reads a dataset written by DatasetWriter. Reads from several threads take turns.
class DatasetReader {
 public:
  /// Opens `path` and checks its layout; mesh scenes need the catalogue the file names
  /// (`mesh_dir` holding <name>/nontextured.stl). Throws std::runtime_error naming the file
  /// and the problem.
  explicit DatasetReader(const std::string& path, const std::string& mesh_dir = "");
  ~DatasetReader();
  const DatasetInfo& info() const;
  int size() const { return info().num_scenes; }
  /// Objects and grid of scene `index` (cheap: no ground-truth arrays).
  SceneRecord readScene(int index) const;
  /// Scene, grid and ground-truth grids of scene `index`.
  SceneRecord read(int index) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Several datasets read as one, to train on piles of several kinds (the paper's 3-4 objects
/// beside crowded or household piles). The scenes are interleaved in proportion to the files'
/// sizes: position i holds the next scene of the file furthest behind its share (least
/// taken / size; the earlier file on a tie), so every tail of the mix, the trainer's
/// validation scenes, holds the last scenes of each file in that proportion. One file reads
/// as itself, scene for scene.
class DatasetMix {
 public:
  /// Opens the files (DatasetReader's `mesh_dir` for each). Throws std::runtime_error naming
  /// the file that cannot be read, whose grids (resolution, extent, truncation) differ from
  /// the first file's, or that holds the same piles as another (one seed and the same first
  /// pile: one file twice), and std::invalid_argument for an empty list.
  explicit DatasetMix(const std::vector<std::string>& paths, const std::string& mesh_dir = "");
  ~DatasetMix();
  int size() const { return static_cast<int>(order_.size()); }
  int files() const { return static_cast<int>(readers_.size()); }
  const DatasetReader& file(int k) const { return *readers_.at(k); }
  const std::string& path(int k) const { return paths_.at(k); }
  /// The paths joined by " + " (the mix as messages and model cards name it).
  std::string name() const;
  /// Where scene `index` of the mix lives: the file and the scene's index in it.
  std::pair<int, int> locate(int index) const { return order_.at(index); }
  SceneRecord read(int index) const;

 private:
  std::vector<std::string> paths_;
  std::vector<std::unique_ptr<DatasetReader>> readers_;
  std::vector<std::pair<int, int>> order_;
};

}  // namespace simstack
