#include "simstack/offline/training/model_writer.h"

#include <fcntl.h>
#include <unistd.h>

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
  // Written, flushed to the disk and renamed: after a crash or a power loss the path holds the
  // previous file or this one whole, never an empty or partial one.
  const std::string tmp = path + ".tmp";
  const std::string data = bytes.str();
  const auto fail = [&](const std::string& doing) {
    const std::string why = std::strerror(errno);
    std::error_code ec;
    std::filesystem::remove(tmp, ec);
    return std::runtime_error("cannot write model " + path + " (" + std::to_string(data.size()) +
                              " bytes, " + doing + "): " + why +
                              "; the file there stays as it was");
  };
  const int fd =
      ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0666);  // the umask applies
  if (fd < 0) throw fail("creating " + tmp);
  for (size_t done = 0; done < data.size();) {
    const ssize_t n = ::write(fd, data.data() + done, data.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const int err = errno;
      ::close(fd);
      errno = err;
      throw fail("writing");
    }
    done += static_cast<size_t>(n);
  }
  if (::fsync(fd) != 0) {
    const int err = errno;
    ::close(fd);
    errno = err;
    throw fail("flushing");
  }
  if (::close(fd) != 0) throw fail("closing");
  std::filesystem::rename(tmp, path);
  // The rename itself reaches the disk with the directory's entry.
  const std::string dir = std::filesystem::path(path).parent_path().string();
  const int dfd = ::open(dir.empty() ? "." : dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd >= 0) {
    ::fsync(dfd);
    ::close(dfd);
  }
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
