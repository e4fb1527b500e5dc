#pragma once
/// @file real_scenes.h
/// The evaluation on labelled real depth (mOSD: Kinect views of table-top objects with a label
/// per pixel): every method on every scene, scored with the unseen-object segmentation
/// literature's measures (segmentation.h: Overlap P/R/F with Hungarian matching, the share of
/// objects found with F above 0.75) and by object counts, overall and by the category the file
/// name gives.

#include <functional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "simstack/offline/eval/evaluator.h"
#include "simstack/offline/eval/segmentation.h"

namespace simstack {

/// One labelled real view: the depth (mOSD intrinsics, the PinholeCamera defaults, unless the
/// cloud is organized with another size) and the object of every valid pixel (-1 table or
/// none).
struct LabelledView {
  std::string name;      ///< the file name
  std::string category;  ///< mosdCategory(name)
  DepthView view;        ///< no table pose: methods estimate it
  Image<int> objects;    ///< label / 10 where the label is >= 20 and the depth valid, else -1
};

/// The mOSD (OSD) category of a file name: learn0-16 and test0-15 "boxes", learn17-24 and
/// test16-23 "stacked boxes", learn25-32 and test24-30 "occluded", learn33-44 and test31-42
/// "cylindrical", test43-54 "mixed", test55-65 "complex"; "" for any other name.
std::string mosdCategory(const std::string& file_name);

/// The .pcd files of `dir` in natural order, learn2 before learn10 (std::runtime_error naming
/// `dir` when it has none).
std::vector<std::string> labelledCloudFiles(const std::string& dir);

/// Reads one labelled cloud (x y z label; organized, or unorganized and organized with the
/// mOSD camera). Throws std::runtime_error naming the file.
LabelledView readLabelledView(const std::string& path);

struct RealSceneResult {
  std::string scene, category;
  int objects = 0, found = 0;  ///< true objects, instances found
  OverlapScores overlap;       ///< over the valid pixels
  bool table_estimated = false;
  double perceive_ms = 0;
  std::optional<int> fits_at_bound;  ///< MethodEstimate::fits_at_bound
  std::optional<double> grid_side_m, object_voxels,
      smallest_object_voxels;  ///< MethodEstimate's, for a network
};

struct RealMethodResults {
  std::string name;
  MethodInfo info;
  std::vector<RealSceneResult> scenes;
};

/// Every method (each must give pixel instances) on every labelled cloud of `dir`, or on the
/// first `max_scenes` of them in labelledCloudFiles' order (0: all).
/// `progress(done, total)` is called after each scene.
std::vector<RealMethodResults> evaluateRealScenes(
    const std::string& dir, const std::vector<EvaluatedMethod*>& methods,
    const std::function<void(int, int)>& progress = {}, int max_scenes = 0);

/// Means over scenes (Overlap P/R/F, %75, count exact share, mean count error and its absolute
/// value) of `scenes` whose category is `category` ("" for all).
nlohmann::json realSummary(const std::vector<RealSceneResult>& scenes,
                           const std::string& category = "");
/// Per method: provenance, the summary overall and by category, and every scene.
nlohmann::json realScenesJson(const std::vector<RealMethodResults>& results);
/// The table the tool prints (GitHub markdown): per method, all scenes then each category.
std::string realScenesTable(const std::vector<RealMethodResults>& results);

}  // namespace simstack
