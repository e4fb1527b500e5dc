#include "simstack/io/staged_output.h"

#include <stdlib.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <vector>

namespace simstack {
namespace fs = std::filesystem;
namespace {

fs::path parentOf(const std::string& target) {
  const fs::path p = fs::absolute(fs::path(target)).lexically_normal();
  std::error_code ec;
  fs::create_directories(p.parent_path(), ec);
  if (ec)
    throw std::runtime_error("cannot create the directory of " + target + ": " + ec.message());
  return p;
}

// A new directory or file name beside `target` (mkdtemp: unique, created by us).
std::string uniqueDirectoryBeside(const fs::path& target, const std::string& what) {
  std::string pattern = target.string() + "." + what + "-XXXXXX";
  std::vector<char> buffer(pattern.begin(), pattern.end());
  buffer.push_back('\0');
  if (!mkdtemp(buffer.data()))
    throw std::runtime_error("cannot write beside " + target.string() + ": " +
                             std::error_code(errno, std::generic_category()).message());
  return buffer.data();
}

}  // namespace

StagedDirectory::StagedDirectory(const std::string& target) {
  const fs::path t = parentOf(target);
  if (fs::exists(t) && !fs::is_directory(t))
    throw std::runtime_error(target + " exists and is not a directory");
  target_ = t.string();
  staged_ = uniqueDirectoryBeside(t, "partial");
}

StagedDirectory::~StagedDirectory() {
  std::error_code ec;
  if (!committed_) fs::remove_all(staged_, ec);
}

void StagedDirectory::commit() {
  std::error_code ec;
  std::string old;
  if (fs::exists(target_)) {
    old = uniqueDirectoryBeside(target_, "old");
    fs::rename(target_, old, ec);  // replaces the empty directory just made
    if (ec)
      throw std::runtime_error("cannot move the earlier " + target_ + " aside: " + ec.message());
  }
  fs::rename(staged_, target_, ec);
  if (ec) throw std::runtime_error("cannot put " + target_ + " in place: " + ec.message());
  committed_ = true;
  if (!old.empty()) fs::remove_all(old, ec);
}

StagedFile::StagedFile(const std::string& target) {
  const fs::path t = parentOf(target);
  if (fs::is_directory(t)) throw std::runtime_error(target + " is a directory");
  target_ = t.string();
  staged_ = target_ + ".partial-" + std::to_string(getpid());
  std::ofstream probe(staged_);  // an unwritable place fails now, not after the work
  if (!probe) throw std::runtime_error("cannot write " + staged_);
}

StagedFile::~StagedFile() {
  std::error_code ec;
  if (!committed_) fs::remove(staged_, ec);
}

void StagedFile::commit() {
  std::error_code ec;
  fs::rename(staged_, target_, ec);
  if (ec) throw std::runtime_error("cannot put " + target_ + " in place: " + ec.message());
  committed_ = true;
}

}  // namespace simstack
