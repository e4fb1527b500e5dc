#include "simstack/offline/eval/real_scenes.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <iomanip>
#include <map>
#include <sstream>
#include <stdexcept>
#include <tuple>

#include "simstack/fitting/superquadric_fit.h"
#include "simstack/io/scene_io.h"

namespace simstack {
namespace {

using nlohmann::json;

/// OSD's categories: the first scene number of each (the learn split has the first four).
struct CategoryStart {
  int learn, test;
  const char* name;
};
constexpr CategoryStart kCategories[] = {{0, 0, "boxes"},      {17, 16, "stacked boxes"},
                                         {25, 24, "occluded"}, {33, 31, "cylindrical"},
                                         {45, 43, "mixed"},    {45, 55, "complex"}};
constexpr int kLearnScenes = 45, kTestScenes = 66;

std::string lowercase(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
  return s;
}

std::string fixed(double value, int digits) {
  if (!std::isfinite(value)) return "-";
  std::ostringstream o;
  o << std::fixed << std::setprecision(digits) << value;
  return o.str();
}

double meanOf(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x;
  return v.empty() ? std::nan("") : s / v.size();
}

/// The categories the scenes hold, in OSD's order.
std::vector<std::string> categoriesOf(const std::vector<RealSceneResult>& scenes) {
  std::vector<std::string> out;
  for (const CategoryStart& c : kCategories)
    for (const RealSceneResult& s : scenes)
      if (s.category == c.name) {
        out.push_back(c.name);
        break;
      }
  return out;
}

}  // namespace

std::string mosdCategory(const std::string& file_name) {
  const std::string stem = lowercase(std::filesystem::path(file_name).stem().string());
  for (const bool learn : {true, false}) {
    const std::string prefix = learn ? "learn" : "test";
    if (stem.rfind(prefix, 0) != 0 || stem.size() == prefix.size() ||
        stem.size() > prefix.size() + 2)
      continue;
    const std::string digits = stem.substr(prefix.size());
    if (!std::all_of(digits.begin(), digits.end(), [](unsigned char c) { return std::isdigit(c); }))
      return "";
    const int n = std::atoi(digits.c_str());
    if (n >= (learn ? kLearnScenes : kTestScenes)) return "";
    std::string category;
    for (const CategoryStart& c : kCategories)
      if (n >= (learn ? c.learn : c.test)) category = c.name;
    return category;
  }
  return "";
}

std::vector<std::string> labelledCloudFiles(const std::string& dir) {
  std::vector<std::string> files;
  for (const auto& e : std::filesystem::directory_iterator(dir))
    if (lowercase(e.path().extension().string()) == ".pcd") files.push_back(e.path().string());
  // Natural order (learn2 before learn10): the digits of a name compared as a number.
  auto key = [](const std::string& path) {
    const std::string stem = std::filesystem::path(path).stem().string();
    size_t d = stem.size();
    while (d > 0 && std::isdigit(static_cast<unsigned char>(stem[d - 1]))) --d;
    const long n = d < stem.size() ? std::atol(stem.c_str() + d) : -1;
    return std::make_tuple(stem.substr(0, d), n, stem);
  };
  std::sort(files.begin(), files.end(),
            [&](const std::string& a, const std::string& b) { return key(a) < key(b); });
  if (files.empty()) throw std::runtime_error("no .pcd files in " + dir);
  return files;
}

LabelledView readLabelledView(const std::string& path) {
  LabelledView out;
  out.name = std::filesystem::path(path).filename().string();
  out.category = mosdCategory(out.name);
  // The Kinect intrinsics mOSD was recorded with: an unorganized cloud is placed on their
  // pixels; an organized one whose points do not fit them gives its own.
  const PinholeCamera mosd;
  Image<uint32_t> labels;
  std::optional<PinholeCamera> own;
  out.view.depth = readDepthPcd(path, &mosd, &labels, &own);
  out.view.camera = own ? *own : mosd;
  out.objects = Image<int>(out.view.depth.width, out.view.depth.height, -1);
  for (size_t i = 0; i < labels.pixels.size(); ++i)
    if (validDepth(out.view.depth.pixels[i]) && labels.pixels[i] >= 20)
      out.objects.pixels[i] = static_cast<int>(labels.pixels[i] / 10);
  return out;
}

std::vector<RealMethodResults> evaluateRealScenes(const std::string& dir,
                                                  const std::vector<EvaluatedMethod*>& methods,
                                                  const std::function<void(int, int)>& progress,
                                                  int max_scenes) {
  std::vector<std::string> files = labelledCloudFiles(dir);
  if (max_scenes > 0 && files.size() > static_cast<size_t>(max_scenes)) files.resize(max_scenes);
  std::vector<RealMethodResults> out;
  for (EvaluatedMethod* m : methods) out.push_back({m->name(), m->info(), {}});
  for (size_t f = 0; f < files.size(); ++f) {
    const LabelledView scene = readLabelledView(files[f]);
    for (size_t k = 0; k < methods.size(); ++k) {
      const MethodEstimate est = methods[k]->estimate(scene.view, nullptr, Vec2::Zero());
      if (est.pixel_instances.pixels.size() != scene.objects.pixels.size())
        throw std::logic_error(methods[k]->name() + " gave no pixel instances");
      std::vector<int> found = est.pixel_instances.pixels;
      for (size_t i = 0; i < found.size(); ++i)  // only valid pixels count
        if (!validDepth(scene.view.depth.pixels[i])) found[i] = -1;
      RealSceneResult r;
      r.scene = scene.name;
      r.category = scene.category;
      r.overlap = overlapScores(scene.objects.pixels, found);
      r.objects = r.overlap.objects;
      r.found = static_cast<int>(est.superquadrics.size());
      r.table_estimated = est.table_estimated;
      r.perceive_ms = est.perceive_ms;
      r.fits_at_bound = est.fits_at_bound;
      if (std::isfinite(est.grid_side_m)) r.grid_side_m = est.grid_side_m;
      if (std::isfinite(est.object_voxels)) r.object_voxels = est.object_voxels;
      if (std::isfinite(est.smallest_object_voxels))
        r.smallest_object_voxels = est.smallest_object_voxels;
      out[k].scenes.push_back(r);
    }
    if (progress) progress(static_cast<int>(f + 1), static_cast<int>(files.size()));
  }
  return out;
}

json realSummary(const std::vector<RealSceneResult>& scenes, const std::string& category) {
  std::vector<double> p, r, f, d, exact, error, abs_error, ms;
  std::optional<int> at_bound;
  for (const RealSceneResult& s : scenes) {
    if (!category.empty() && s.category != category) continue;
    p.push_back(s.overlap.precision);
    r.push_back(s.overlap.recall);
    f.push_back(s.overlap.f_measure);
    d.push_back(s.overlap.detected_075);
    exact.push_back(s.found == s.objects ? 1.0 : 0.0);
    error.push_back(s.found - s.objects);
    abs_error.push_back(std::abs(s.found - s.objects));
    ms.push_back(s.perceive_ms);
    if (s.fits_at_bound) at_bound = at_bound.value_or(0) + *s.fits_at_bound;
  }
  return {{"scenes", p.size()},
          {"overlap_precision", meanOf(p)},
          {"overlap_recall", meanOf(r)},
          {"overlap_f", meanOf(f)},
          {"detected_075", meanOf(d)},
          {"count_exact", meanOf(exact)},
          {"count_error", meanOf(error)},
          {"count_abs_error", meanOf(abs_error)},
          {"perceive_ms", meanOf(ms)},
          {"fits_at_bound", at_bound ? json(*at_bound) : json(nullptr)}};
}

json realScenesJson(const std::vector<RealMethodResults>& results) {
  json out;
  for (const RealMethodResults& m : results) {
    json j;
    j["model"] = m.info.model;
    if (!m.info.config_yaml.empty()) j["config"] = m.info.config_yaml;
    j["summary"] = realSummary(m.scenes);
    for (const std::string& c : categoriesOf(m.scenes))
      j["by_category"][c] = realSummary(m.scenes, c);
    j["scenes"] = json::array();
    for (const RealSceneResult& s : m.scenes)
      j["scenes"].push_back(
          {{"scene", s.scene},
           {"category", s.category},
           {"objects", s.objects},
           {"found", s.found},
           {"instances_on_pixels", s.overlap.instances},
           {"overlap_precision", s.overlap.precision},
           {"overlap_recall", s.overlap.recall},
           {"overlap_f", s.overlap.f_measure},
           {"detected_075", s.overlap.detected_075},
           {"table_estimated", s.table_estimated},
           {"perceive_ms", s.perceive_ms},
           {"fits_at_bound", s.fits_at_bound ? json(*s.fits_at_bound) : json(nullptr)},
           {"grid_side_m", s.grid_side_m ? json(*s.grid_side_m) : json(nullptr)},
           {"object_voxels", s.object_voxels ? json(*s.object_voxels) : json(nullptr)},
           {"smallest_object_voxels",
            s.smallest_object_voxels ? json(*s.smallest_object_voxels) : json(nullptr)}});
    out[m.name] = j;
  }
  return out;
}

std::string realScenesTable(const std::vector<RealMethodResults>& results) {
  std::ostringstream o;
  o << "| method | scenes | Overlap P | Overlap R | Overlap F | %75 | count exact | count error "
       "| absolute count error |\n|---|---|---|---|---|---|---|---|---|\n";
  for (const RealMethodResults& m : results) {
    std::vector<std::string> rows{""};
    for (const std::string& c : categoriesOf(m.scenes)) rows.push_back(c);
    for (const std::string& c : rows) {
      const json s = realSummary(m.scenes, c);
      const auto percent = [&](const char* key) { return fixed(100 * s[key].get<double>(), 1); };
      o << "| " << m.name << (c.empty() ? "" : ": " + c) << " | " << s["scenes"].get<int>() << " | "
        << percent("overlap_precision") << " | " << percent("overlap_recall") << " | "
        << percent("overlap_f") << " | " << percent("detected_075") << " | "
        << fixed(100 * s["count_exact"].get<double>(), 0) << " % | "
        << fixed(s["count_error"].get<double>(), 2) << " | "
        << fixed(s["count_abs_error"].get<double>(), 2) << " |\n";
    }
  }
  bool first = true;
  for (const RealMethodResults& m : results) {
    const json at_bound = realSummary(m.scenes)["fits_at_bound"];
    if (at_bound.is_null()) continue;  // a method that keeps no measured points per object
    o << (first ? "\n" : "") << m.name << ": " << at_bound.get<int>()
      << " superquadrics at the fitter's lower bound for objects seen over "
      << fixed(100 * kCollapseSpanM, 0) << " cm, in " << m.scenes.size() << " scenes\n";
    first = false;
  }
  return o.str();
}

}  // namespace simstack
