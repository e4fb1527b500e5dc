#pragma once
/// @file dataset_generation.h
/// Making a dataset (simstack_generate): random piles settled under physics, their ground-truth
/// grids written to HDF5 in scene order, and optionally rendered views beside it (a 16-bit depth
/// PNG in mm, the instance mask, a YAML with intrinsics and pose, and pictures). Scene i uses a
/// hash of (seed, i), so the dataset does not depend on the number of threads; a scene whose
/// seed gives no pile is drawn again from seeds derived from it (GenerationOptions::redraws).

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "simstack/render/depth_renderer.h"

namespace simstack {

struct GenerationOptions {
  int scenes = 10;
  uint64_t seed = 1;
  int resolution = 32;
  std::string output;  ///< the HDF5 file
  int min_objects = 3, max_objects = 4;
  std::string ycb_dir;  ///< mesh piles of <dir>/<object>/nontextured.stl ("" = superquadrics)
  /// The objects of `ycb_dir` drawn into the piles (empty: ycbObjectNames(), the paper's ten);
  /// a subset leaves the others out of training piles, to be met first in evaluation.
  std::vector<std::string> ycb_objects;
  /// Share of the objects drawn from household shapes (household.h); superquadric piles only.
  double household_share = 0.0;
  /// Drops scattered 15 cm about the pile's centre and piles kept when not one stack.
  bool loose = false;
  int views = 0;          ///< rendered views per scene
  std::string views_dir;  ///< "" = <output stem>_views/
  bool pictures = false;  ///< colour depth and shaded ground-truth PNGs per view
  bool noise = false;     ///< sensor noise and missing pixels in the rendered views
  SensorModel sensor = SensorModel::kinect;  ///< whose noise (SensorNoiseConfig::preset)
  PinholeCamera camera;                      ///< the views' camera (a 640x480 Kinect)
  double extent_m = 0.64;
  double truncation_vox = 3.0;
  double max_tilt_deg = 180.0;
  /// Superquadrics' full extent along each axis, drawn uniformly (YCB meshes keep their size).
  double min_size_m = 0.05, max_size_m = 0.30;
  /// A scene whose pile cannot be made (no pile accepted in the generator's attempts) is drawn
  /// again from another seed, at most this many times, before the run fails.
  int redraws = 3;
  int threads = 2;
};

struct GenerationSummary {
  long objects = 0;
  /// Piles by object count (index: objects). Piles of more objects are rejected more often,
  /// so the counts of MIN:MAX lean towards MIN.
  std::vector<int> piles_with;
  long attempts = 0;        ///< piles drawn for the accepted ones
  int skipped = 0;          ///< scenes drawn again because no pile could be made from their seed
  double undone_share = 0;  ///< share of the physics spent on drops and piles undone
  double seconds = 0;
  int threads = 0;
  double truncation_m = 0;
  std::string views_dir;  ///< where the views went ("" without views)
};

/// Generates `options.scenes` piles into `options.output`. `progress(done, total)` after each
/// scene written. Throws std::runtime_error naming the scene or file that failed.
GenerationSummary generateDataset(const GenerationOptions& options,
                                  const std::function<void(int, int)>& progress = {});

}  // namespace simstack
