#include "simstack/offline/training/model_writer.h"

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <stdexcept>

#include "simstack/model/model_integrity.h"

namespace simstack {

void saveCvae(const std::string& path, Cvae& model, const std::string& metadata,
              const std::function<void(torch::serialize::OutputArchive&)>& extra) {
  torch::serialize::OutputArchive archive;
  model->save(archive);
  if (extra) extra(archive);
  archive.write("simstack_format", torch::IValue(modelFormatVersion()));
  archive.write("simstack_config", torch::IValue(model->config().toYaml()));
  archive.write("simstack_metadata", torch::IValue(metadata));
  // Serialized in memory, then written and checked here: libtorch's file writer aborts the
  // process when a write fails (a full disk) instead of throwing.
  std::ostringstream bytes(std::ios::binary);
  try {
    archive.save_to(bytes);
  } catch (const c10::Error& e) {
    throw std::runtime_error("cannot write model " + path + ": " + e.what_without_backtrace());
  }
  const std::string tmp = path + ".tmp";
  {
    std::ofstream file(tmp, std::ios::binary | std::ios::trunc);
    const std::string data = bytes.str();
    file.write(data.data(), static_cast<std::streamsize>(data.size()));
    file.flush();
    if (!file) {
      const std::string why = std::strerror(errno);
      file.close();
      std::error_code ec;
      std::filesystem::remove(tmp, ec);
      throw std::runtime_error("cannot write model " + path + " (" + std::to_string(data.size()) +
                               " bytes): " + why + "; the file there stays as it was");
    }
  }
  std::filesystem::rename(tmp, path);  // a crash never leaves half a file behind
}

std::vector<std::string> warmStartCvae(Cvae& model, const std::string& path) {
  Cvae source = loadCvae(path);
  const std::map<std::string, torch::Tensor> from = cvaeTensors(source);
  std::vector<std::string> fresh;
  size_t copied = 0;
  torch::NoGradGuard no_grad;
  for (auto& [name, to] : cvaeTensors(model)) {
    const auto it = from.find(name);
    if (it == from.end()) {
      fresh.push_back(name);
      continue;
    }
    if (it->second.sizes() != to.sizes()) {
      throw std::runtime_error("warm start from " + path + ": tensor " + name + " has shape " +
                               c10::str(it->second.sizes()) + ", this network's " +
                               c10::str(to.sizes()));
    }
    to.copy_(it->second);
    ++copied;
  }
  if (copied == 0)
    throw std::runtime_error("warm start from " + path +
                             ": the file shares no tensor with this network");
  return fresh;
}

}  // namespace simstack
