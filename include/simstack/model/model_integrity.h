#pragma once
/// @file model_integrity.h
/// A model file proves itself on load. Its card (models/<name>.yaml) records, in `integrity:`,
/// the file's SHA-256, simstack's model format version and what the pipeline perceives with it
/// on a canned scene (ScenePerception's self-test, pipeline/scene_perception.h); loading checks
/// the hash and the format before the weights are read (a file damaged on disk or in a copy is
/// refused by name, not run as a network that sees nothing), and every tensor is checked finite
/// when read (loadCvae).

#include <optional>
#include <string>

namespace simstack {

/// What a model's card says of its file.
struct ModelIntegrity {
  std::string sha256;      ///< of the .pt file, 64 lower-case hex digits
  int format_version = 0;  ///< simstack's model file format the file was written in
  /// The self-test's expected result: objects and voxels occupied (probability >= 0.5) that the
  /// pipeline's defaults perceive on a rendered box with this model; -1 when not recorded.
  int self_test_objects = -1;
  int self_test_occupied_voxels = -1;
};

/// The model file format this build writes and reads.
int modelFormatVersion();
/// SHA-256 of a file's bytes, 64 lower-case hex digits; std::runtime_error naming the file when
/// it cannot be read.
std::string sha256OfFile(const std::string& path);
/// The `integrity:` section of the card of the model at `model_path`; std::nullopt when the
/// model has no card or the card no such section. std::runtime_error naming the card and field
/// for a malformed one.
std::optional<ModelIntegrity> readModelIntegrity(const std::string& model_path);
/// Checks the model file against its card's `integrity:` (SHA-256, format); nothing to check
/// without one. std::runtime_error naming the file, the card and the check that failed, or
/// saying that a card (.yaml) was given where its model belongs (requireModelNotCard).
void verifyModelFile(const std::string& model_path);
/// std::runtime_error when `model_path` names a model card (.yaml, .yml) rather than a model.
void requireModelNotCard(const std::string& model_path);
/// Writes `integrity` as the `integrity:` section of the card of `model_path` (creating the
/// card when there is none), the rest of the card kept.
void writeModelIntegrity(const std::string& model_path, const ModelIntegrity& integrity);

}  // namespace simstack
