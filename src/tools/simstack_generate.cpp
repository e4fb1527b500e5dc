// simstack_generate: random piles settled under physics -> HDF5 dataset of ground-truth grids,
// optionally with rendered views (16-bit depth PNG in mm, instance mask, YAML) and pictures
// (dataset/dataset_generation.h).
#include <CLI/CLI.hpp>

#include <iomanip>
#include <iostream>

#include "cli_checks.h"
#include "perception_options.h"
#include "progress.h"
#include "sensor_option.h"
#include "simstack/offline/dataset/dataset_generation.h"

using namespace simstack;

namespace {

std::pair<double, double> parseSizes(const std::string& s) {
  const auto colon = s.find(':');
  try {
    if (colon == std::string::npos) throw std::invalid_argument(s);
    size_t a = 0, b = 0;
    const double lo = std::stod(s.substr(0, colon), &a), hi = std::stod(s.substr(colon + 1), &b);
    if (a != colon || b != s.size() - colon - 1) throw std::invalid_argument(s);
    return {lo, hi};
  } catch (const std::exception&) {
    throw CLI::ValidationError("--sizes", "expected MIN:MAX in metres, got '" + s + "'");
  }
}

/// MIN:MAX or N objects, 1 <= MIN <= MAX <= 254 (the labels are 8-bit, 0 is free space).
std::pair<int, int> parseRange(const std::string& s) {
  const auto whole = [](const std::string& t) {
    size_t used = 0;
    const int n = std::stoi(t, &used);
    if (used != t.size()) throw std::invalid_argument(t);
    return n;
  };
  std::pair<int, int> r;
  try {
    const auto colon = s.find(':');
    r = colon == std::string::npos
            ? std::pair<int, int>{whole(s), whole(s)}
            : std::pair<int, int>{whole(s.substr(0, colon)), whole(s.substr(colon + 1))};
  } catch (const std::exception&) {
    throw CLI::ValidationError("--objects", "expected MIN:MAX or N, got '" + s + "'");
  }
  if (r.first < 1 || r.second < r.first || r.second > 254)
    throw CLI::ValidationError("--objects",
                               "the object count '" + s + "' must satisfy 1 <= MIN <= MAX <= 254");
  return r;
}

/// A name of --ycb-objects: not empty ("" given).
const CLI::Validator kMeshName(
    [](std::string& name) {
      return name.empty() ? std::string("an empty object name") : std::string();
    },
    "NAME");

/// The rendered views' camera as given: --width, --height, --intrinsics.
struct ViewCamera {
  int width = 640, height = 480;
  std::string intrinsics;
};

/// --views and what they are: where, pictures, noise, sensor and camera.
void addViewOptions(CLI::App& app, GenerationOptions* o, ViewCamera* camera) {
  app.add_option("--views", o->views, "rendered views per scene written beside the dataset")
      ->capture_default_str()
      ->check(FiniteNonNegative);
  // The options of the views do nothing without them: refused in main, not ignored.
  app.add_option("--views-dir", o->views_dir, "where views go (default: <output stem>_views/)")
      ->check(WritablePath);
  app.add_flag("--pictures", o->pictures,
               "also write colour depth and shaded PNG pictures of each view");
  CLI::Option* noise_flag = app.add_flag(
      "--noise", o->noise, "sensor noise and missing pixels in the rendered views (--sensor's)");
  addSensorOption(app, &o->sensor, "with --noise, ")->needs(noise_flag);
  app.add_option("--width", camera->width,
                 "view width (pixels): fx scales with the width, fy with the height, so keep 4:3 "
                 "for square pixels")
      ->capture_default_str()
      ->check(CLI::Range(16, 4096))
      ->needs("--views");
  app.add_option("--height", camera->height, "view height (pixels)")
      ->capture_default_str()
      ->check(CLI::Range(16, 4096))
      ->needs("--views");
  app.add_option("--intrinsics", camera->intrinsics,
                 "fx,fy,cx,cy (pixels) of another camera for the --width x --height views, "
                 "instead of the scaled Kinect (e.g. a D435's with --sensor realsense)")
      ->needs("--views");
}

/// What was written: scenes, grid, acceptance, piles by object count, redraws, views.
void printSummary(const GenerationOptions& o, const GenerationSummary& s) {
  std::cout << std::fixed << std::setprecision(1) << "wrote " << o.scenes << " scenes ("
            << s.objects << " objects, "
            << (!o.ycb_dir.empty()        ? "YCB meshes"
                : o.household_share > 0.0 ? "superquadrics and household shapes"
                                          : "superquadrics")
            << ") to " << o.output << "\n"
            << "  grid " << o.resolution << "^3, " << o.extent_m / o.resolution * 100.0
            << " cm voxels, truncation " << s.truncation_m * 100.0 << " cm\n"
            << "  " << s.attempts << " piles drawn for " << o.scenes << " accepted ("
            << 100.0 * o.scenes / s.attempts << " % accepted), " << o.scenes / s.seconds
            << " scenes/s on " << s.threads << (s.threads == 1 ? " thread; " : " threads; ")
            << 100.0 * s.undone_share
            << " % of the physics went to drops and piles that were undone\n";
  std::cout << "  piles by object count:";
  const char* sep = " ";
  for (size_t k = 0; k < s.piles_with.size(); ++k)
    if (s.piles_with[k] > 0) {
      std::cout << sep << s.piles_with[k] << " of " << k;
      sep = ", ";
    }
  std::cout << "\n";
  if (s.skipped > 0)
    std::cout << "  " << s.skipped
              << " scenes drawn again: no pile could be made from their seed\n";
  if (o.views > 0) std::cout << "  " << o.views << " views per scene in " << s.views_dir << "/\n";
}

}  // namespace

int main(int argc, char** argv) {
  GenerationOptions o;
  std::string objects = "3:4", sizes = "0.05:0.3";
  CLI::App app{
      "Generate random piles settled under Bullet physics and write the HDF5 dataset "
      "of ground-truth TSDF, centre votes and labels (docs/design.md section 5)."};
  app.add_option("--scenes", o.scenes, "number of piles")->required()->check(FinitePositive);
  app.add_option("--seed", o.seed, "random seed (scene i uses a hash of seed and i)")
      ->required()
      ->transform(SeedNumber);
  app.add_option("--resolution", o.resolution, "grid resolution R (R^3 voxels)")
      ->check(CLI::Range(4, 256))
      ->capture_default_str();
  app.add_option("--output", o.output, "output HDF5 file")->required()->check(WritablePath);
  app.add_option("--objects", objects, "objects per pile, MIN:MAX or N")->capture_default_str();
  app.add_option("--sizes", sizes,
                 "superquadrics' full extent along each axis, MIN:MAX metres (drawn uniformly); "
                 "smaller objects make piles of more objects fit the grid")
      ->capture_default_str();
  app.add_option("--redraws", o.redraws,
                 "times a scene whose pile cannot be made is drawn again from another seed "
                 "before the run fails")
      ->check(CLI::Range(0, 100))
      ->capture_default_str();
  app.add_option("--ycb", o.ycb_dir,
                 "directory of YCB meshes (<dir>/<object>/nontextured.stl): mesh piles instead of "
                 "superquadrics");
  app.add_option("--ycb-objects", o.ycb_objects,
                 "with --ycb: the objects drawn, NAME[,NAME...] (subdirectories of --ycb; default "
                 "the paper's ten)")
      ->delimiter(',')
      ->check(kMeshName)
      ->needs("--ycb");
  app.add_option("--household", o.household_share,
                 "share of the objects drawn from household shapes: bowls and cups (concave "
                 "meshes), flat, thin and small superquadrics; 0 = the paper's piles")
      ->check(FiniteNonNegative & CLI::Range(0.0, 1.0))
      ->excludes("--ycb")
      ->capture_default_str();
  app.add_flag("--loose", o.loose,
               "objects dropped 15 cm about the centre and kept side by side: piles need not be "
               "one stack (real tables)");
  ViewCamera camera;
  addViewOptions(app, &o, &camera);
  app.add_option("--extent", o.extent_m, "scene grid side in metres (at most 10)")
      ->check(FinitePositive & CLI::Range(0.0, 10.0))
      ->capture_default_str();
  app.add_option("--truncation-vox", o.truncation_vox, "TSDF truncation in voxels (0.5-64)")
      ->check(FinitePositive & CLI::Range(0.5, 64.0))
      ->capture_default_str();
  app.add_option("--max-tilt", o.max_tilt_deg,
                 "drop orientation: a face down, random yaw, tilt up to this many degrees; 180 = "
                 "uniformly random (the paper); 0 settles faster but gives neater, taller piles")
      ->check(FiniteNonNegative & CLI::Range(0.0, 180.0))  // Range alone lets "nan" through
      ->capture_default_str();
  app.add_option("--threads", o.threads, "worker threads")
      ->check(CLI::Range(1, 64))
      ->capture_default_str();
  readIntegersInDecimal(app);
  CLI11_PARSE(app, argc, argv);

  try {
    if (o.views == 0 && (o.noise || o.pictures || !o.views_dir.empty()))
      throw std::invalid_argument(
          "--noise, --pictures and --views-dir are for the rendered views: give --views K > 0");
    std::tie(o.min_objects, o.max_objects) = parseRange(objects);
    std::tie(o.min_size_m, o.max_size_m) = parseSizes(sizes);
    o.camera = camera.intrinsics.empty()
                   ? scaledKinect(camera.width, camera.height)
                   : parseIntrinsics(camera.intrinsics, camera.width, camera.height);
    ProgressBar bar("generating", o.scenes);
    const GenerationSummary s = generateDataset(o, [&](int done, int) { bar.update(done); });
    bar.finish();
    printSummary(o, s);
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "simstack_generate: error: " << e.what() << "\n";
    return 1;
  }
}
