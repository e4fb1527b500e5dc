// simstack_check_model: whether a model file is the one its card describes and still works (its
// SHA-256 and format, finite weights, the self-test on a rendered box), as every tool and the
// node check it on load; --stamp records the file's own figures in its card.
#include <CLI/CLI.hpp>

#include <cstdio>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <vector>

#include "simstack/model/cvae_config.h"
#include "simstack/model/model_integrity.h"
#include "simstack/pipeline/perception_config.h"
#include "simstack/pipeline/scene_perception.h"

using namespace simstack;

int main(int argc, char** argv) {
  std::vector<std::string> models;
  bool stamp = false;
  CLI::App app{
      "Check model files as loading does: the SHA-256 and format their card records, finite "
      "weights, and the self-test (what the pipeline's defaults perceive on a rendered box) "
      "against the card's. Exits 1 naming the first model that fails."};
  app.add_option("models", models, "model files (.pt, each with its card .yaml beside it)")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_flag("--stamp", stamp,
               "write each file's SHA-256, format and self-test into its card's integrity: "
               "section (after training, or after replacing the file on purpose); the weights "
               "must still be finite");
  CLI11_PARSE(app, argc, argv);
  try {
    for (const std::string& model : models) {
      if (stamp) {
        const ModelIntegrity m = stampModel(model);
        std::printf(
            "%s: stamped into %s: sha256 %s, format %d, self-test %d object(s), %d "
            "occupied voxels\n",
            model.c_str(), modelCardPath(model).c_str(), m.sha256.c_str(), m.format_version,
            m.self_test_objects, m.self_test_occupied_voxels);
        continue;
      }
      const ModelSelfTest t = checkModel(model);
      const bool recorded = readModelIntegrity(model).has_value();
      // The card's perception: section, read and checked as a perception loading the model
      // does (its samples and Hough setting).
      PerceptionConfig card;
      card.model_path = model;
      if (!applyModelCard(&card).empty()) {
        try {
          card.hough.validate();
          if (card.samples < 1 || card.samples > kMaxSamples)
            throw std::invalid_argument("samples must lie in [1, " + std::to_string(kMaxSamples) +
                                        "], not " + std::to_string(card.samples));
        } catch (const std::invalid_argument& e) {
          throw std::runtime_error(modelCardPath(model) + ": perception." + e.what());
        }
      }
      const bool has_card = std::filesystem::exists(modelCardPath(model));
      std::printf("%s: ok: %s; self-test %d object(s), %d occupied voxels\n", model.c_str(),
                  recorded   ? "SHA-256 and format as its card records"
                  : has_card ? "its card records no integrity: section (--stamp writes one)"
                             : "no card beside it (--stamp writes one)",
                  t.objects, t.occupied_voxels);
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "simstack_check_model: %s\n", e.what());
    return 1;
  }
  return 0;
}
