#include "simstack/model/model_integrity.h"

#include <openssl/evp.h>
#include <yaml-cpp/yaml.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <stdexcept>

#include "simstack/io/yaml_file.h"
#include "simstack/model/cvae_config.h"  // modelCardPath, loadModelCard

namespace simstack {

int modelFormatVersion() { return 1; }

std::string sha256OfFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error("cannot read " + path + " to check its SHA-256");
  const std::unique_ptr<EVP_MD_CTX, decltype(&EVP_MD_CTX_free)> ctx(EVP_MD_CTX_new(),
                                                                    &EVP_MD_CTX_free);
  if (!ctx || EVP_DigestInit_ex(ctx.get(), EVP_sha256(), nullptr) != 1)
    throw std::runtime_error("OpenSSL could not start a SHA-256");
  std::array<char, 1 << 16> buffer;
  while (in.read(buffer.data(), buffer.size()) || in.gcount() > 0) {
    if (EVP_DigestUpdate(ctx.get(), buffer.data(), static_cast<size_t>(in.gcount())) != 1)
      throw std::runtime_error("OpenSSL could not hash " + path);
    if (in.eof()) break;
  }
  if (in.bad()) throw std::runtime_error("cannot read " + path + " to check its SHA-256");
  std::array<unsigned char, EVP_MAX_MD_SIZE> digest;
  unsigned int size = 0;
  if (EVP_DigestFinal_ex(ctx.get(), digest.data(), &size) != 1)
    throw std::runtime_error("OpenSSL could not finish the SHA-256 of " + path);
  std::string hex;
  char byte[3];
  for (unsigned int i = 0; i < size; ++i) {
    std::snprintf(byte, sizeof(byte), "%02x", digest[i]);
    hex += byte;
  }
  return hex;
}

std::optional<ModelIntegrity> readModelIntegrity(const std::string& model_path) {
  const std::string card = modelCardPath(model_path);
  if (model_path.empty() || !std::filesystem::exists(card)) return std::nullopt;
  const YAML::Node root = loadModelCard(card);
  const YAML::Node n = root["integrity"];
  if (!n) return std::nullopt;
  ModelIntegrity m;
  try {
    if (!n.IsMap()) throw std::runtime_error("'integrity' must be a map");
    for (const auto& kv : n) {
      const std::string key = kv.first.as<std::string>();
      if (key == "format")
        throw std::runtime_error(
            "integrity.format is read as format_version (restamp the card: simstack_check_model "
            "--stamp)");
      if (key != "sha256" && key != "format_version" && key != "self_test")
        throw std::runtime_error("unknown field integrity." + key);
    }
    m.sha256 = n["sha256"].as<std::string>();
    m.format_version = n["format_version"].as<int>();
    if (const YAML::Node t = n["self_test"]) {
      m.self_test_objects = t["objects"].as<int>();
      m.self_test_occupied_voxels = t["occupied_voxels"].as<int>();
    }
  } catch (const std::exception& e) {
    throw std::runtime_error(card + ": integrity: " + e.what() +
                             " (sha256, format_version and self_test {objects, occupied_voxels}; "
                             "simstack_check_model --stamp writes them)");
  }
  return m;
}

void requireModelNotCard(const std::string& model_path) {
  const std::filesystem::path p(model_path);
  if (p.extension() == ".yaml" || p.extension() == ".yml")
    throw std::runtime_error(model_path + " is a model card, not a model: give the model file " +
                             "it describes (" +
                             std::filesystem::path(p).replace_extension(".pt").string() + ")");
}

void verifyModelFile(const std::string& model_path) {
  requireModelNotCard(model_path);
  const std::optional<ModelIntegrity> m = readModelIntegrity(model_path);
  if (!m) return;
  const std::string card = modelCardPath(model_path);
  if (m->format_version != modelFormatVersion())
    throw std::runtime_error("model " + model_path + ": its card " + card + " says format " +
                             std::to_string(m->format_version) + ", this build reads format " +
                             std::to_string(modelFormatVersion()));
  if (!std::filesystem::exists(model_path))
    throw std::runtime_error("model file not found: " + model_path);
  const std::string actual = sha256OfFile(model_path);
  if (actual != m->sha256)
    throw std::runtime_error("model " + model_path +
                             " failed its SHA-256 check: the file hashes "
                             "to " +
                             actual + ", its card " + card + " records " + m->sha256 +
                             " (the file is damaged, or is not the model the card describes)");
}

void writeModelIntegrity(const std::string& model_path, const ModelIntegrity& m) {
  YAML::Emitter e;
  e << YAML::BeginMap << YAML::Key << "integrity" << YAML::Value << YAML::BeginMap;
  e << YAML::Key << "sha256" << YAML::Value << m.sha256;
  e << YAML::Key << "format_version" << YAML::Value << m.format_version;
  if (m.self_test_objects >= 0)
    e << YAML::Key << "self_test" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key
      << "objects" << YAML::Value << m.self_test_objects << YAML::Key << "occupied_voxels"
      << YAML::Value << m.self_test_occupied_voxels << YAML::EndMap;
  e << YAML::EndMap << YAML::EndMap;
  const std::string section =
      "# checked whenever the model is loaded: the file's SHA-256 and format, then what the\n"
      "# pipeline's defaults perceive on a rendered box (simstack_train or simstack_check_model\n"
      "# --stamp writes it)\n" +
      std::string(e.c_str()) + "\n";
  writeTopLevelSection(modelCardPath(model_path), "integrity", section, "model card");
}

}  // namespace simstack
