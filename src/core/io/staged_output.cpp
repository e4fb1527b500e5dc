#include "simstack/io/staged_output.h"

#include <signal.h>
#include <stdlib.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace simstack {
namespace fs = std::filesystem;
namespace {

/// Absolute and normal, "out/" as "out".
fs::path normalPath(const fs::path& path) {
  fs::path p = fs::absolute(path).lexically_normal();
  if (p.filename().empty()) p = p.parent_path();
  return p;
}

fs::path parentOf(const std::string& target) {
  const fs::path p = normalPath(target);
  std::error_code ec;
  fs::create_directories(p.parent_path(), ec);
  if (ec)
    throw std::runtime_error("cannot create the directory of " + target + ": " + ec.message());
  return p;
}

/// ".partial-<host>-": after a target's name, the prefix of this host's staged outputs for it;
/// the process id follows, so that a later run can tell which of them no process writes any
/// more.
std::string partialTag() {
  char host[256] = {};
  if (gethostname(host, sizeof(host) - 1) != 0 || host[0] == '\0') std::strcpy(host, "host");
  return std::string(".partial-") + host + "-";
}

/// Removes the staged outputs for `target` that this host's processes left when they were
/// killed (SIGKILL, the OOM killer): those whose process no longer runs. Another host's (a
/// shared file system) are left alone, as are those of a live process.
void removeStalePartials(const fs::path& target) {
  const std::string prefix = target.filename().string() + partialTag();
  std::error_code ec;
  for (const fs::directory_entry& e : fs::directory_iterator(target.parent_path(), ec)) {
    const std::string name = e.path().filename().string();
    if (name.compare(0, prefix.size(), prefix) != 0) continue;
    const std::string rest = name.substr(prefix.size());
    const size_t end = std::min(rest.find_first_not_of("0123456789"), rest.size());
    if (end == 0 || end > 9) continue;
    const pid_t pid = static_cast<pid_t>(std::stol(rest.substr(0, end)));
    if (kill(pid, 0) == 0 || errno != ESRCH) continue;  // alive, or not ours to ask about
    std::error_code ignored;
    fs::remove_all(e.path(), ignored);
  }
}

/// Where this process stages its output for `target`: "<target>.partial-<host>-<pid>".
std::string stagedStem(const fs::path& target) {
  return target.string() + partialTag() + std::to_string(getpid());
}

// A new directory named `stem` and a unique suffix (mkdtemp: created by us).
std::string uniqueDirectory(const std::string& stem) {
  std::string pattern = stem + "-XXXXXX";
  std::vector<char> buffer(pattern.begin(), pattern.end());
  buffer.push_back('\0');
  if (!mkdtemp(buffer.data()))
    throw std::runtime_error("cannot write " + stem +
                             "-*: " + std::error_code(errno, std::generic_category()).message());
  return buffer.data();
}

constexpr const char* kMarker = ".simstack-output";

/// Which tool's result `dir` is ("" when it holds no marker).
std::string ownerOf(const fs::path& dir) {
  std::ifstream in(dir / kMarker);
  std::string owner;
  std::getline(in, owner);
  return owner;
}

/// The files under `dir` (relative, sorted), the marker left out.
std::vector<std::string> filesUnder(const fs::path& dir) {
  std::vector<std::string> files;
  std::error_code ec;
  for (fs::recursive_directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    if (it->is_directory(ec)) continue;
    const std::string name = it->path().lexically_relative(dir).string();
    if (name != kMarker) files.push_back(name);
  }
  std::sort(files.begin(), files.end());
  return files;
}

/// The files an earlier result in `dir` holds that its run did not write, as the marker lists
/// them after the owner's line (none is known of a marker without the list).
std::vector<std::string> filesAddedTo(const fs::path& dir) {
  std::ifstream in(dir / kMarker);
  std::string line;
  std::getline(in, line);
  std::vector<std::string> written;
  while (std::getline(in, line)) written.push_back(line);
  if (written.empty()) return {};
  std::sort(written.begin(), written.end());
  std::vector<std::string> added;
  for (const std::string& file : filesUnder(dir))
    if (!std::binary_search(written.begin(), written.end(), file)) added.push_back(file);
  return added;
}

}  // namespace

std::string unwritablePath(const std::string& path) {
  if (path.empty()) return "the path is empty: name a file or directory";
  for (const char c : path)
    if (static_cast<unsigned char>(c) < 0x20 || c == 0x7f)
      return "the path holds a control character (code " +
             std::to_string(static_cast<int>(static_cast<unsigned char>(c))) +
             ", a newline or tab, say): names may not";
  if (path.size() > 4096)
    return "the path is " + std::to_string(path.size()) + " bytes long: at most 4096";
  for (const auto& part : fs::path(path))
    if (part.native().size() > kMaxFileNameBytes)
      return "a name in the path is " + std::to_string(part.native().size()) +
             " bytes long: at most " + std::to_string(kMaxFileNameBytes) +
             " (the file system's limit)";
  return "";
}

bool pathHolds(const std::string& outer, const std::string& inner) {
  const fs::path o = normalPath(outer), i = normalPath(inner);
  return std::mismatch(o.begin(), o.end(), i.begin(), i.end()).first == o.end();
}

StagedDirectory::StagedDirectory(const std::string& target, const std::string& owner) {
  const fs::path t = parentOf(target);
  if (fs::exists(t) && !fs::is_directory(t))
    throw std::runtime_error(target + " exists and is not a directory");
  // Replacing the working directory (or one holding it) would leave the caller in a deleted one.
  if (pathHolds(target, "."))
    throw std::runtime_error(target +
                             " is the working directory or holds it: name a directory inside "
                             "it, e.g. " +
                             (fs::path(target) / "out").string());
  // Only an earlier result of the same tool is replaced: never a directory of the user's files,
  // nor another tool's result (the reconstruction a grasp ranking reads, say).
  if (fs::is_directory(t) && !fs::is_empty(t) && ownerOf(t) != owner) {
    const std::string other = ownerOf(t);
    throw std::runtime_error(
        target + " is not empty and is not an earlier result of " + owner +
        (other.empty() ? std::string(" (it has no ") + kMarker + ")" : " but of " + other) +
        ": choose another directory, or empty it");
  }
  // Files put into an earlier result since (the inputs of this run, say) would go with it.
  if (fs::is_directory(t) && ownerOf(t) == owner) {
    const std::vector<std::string> added = filesAddedTo(t);
    if (!added.empty()) {
      std::string names;
      for (size_t k = 0; k < std::min<size_t>(added.size(), 3); ++k)
        names += (k ? ", " : "") + added[k];
      if (added.size() > 3) names += " and " + std::to_string(added.size() - 3) + " more";
      throw std::runtime_error(target + " holds files its earlier " + owner +
                               " run did not write (" + names +
                               "), which replacing it would remove: move them out, or choose "
                               "another directory");
    }
  }
  target_ = t.string();
  removeStalePartials(t);
  staged_ = uniqueDirectory(stagedStem(t));
  // mkdtemp makes it private (0700); a result directory gets the usual mode.
  const mode_t mask = ::umask(0);
  ::umask(mask);
  std::error_code ec;
  fs::permissions(staged_, static_cast<fs::perms>(0777 & ~mask), ec);
  std::ofstream marker(fs::path(staged_) / kMarker);
  marker << owner << "\n";
  if (!marker) throw std::runtime_error("cannot write in " + staged_);
}

StagedDirectory::~StagedDirectory() {
  std::error_code ec;
  if (!committed_) fs::remove_all(staged_, ec);
}

void StagedDirectory::commit() {
  std::error_code ec;
  {
    // The marker lists what this run wrote, so that a later run can tell a file added since.
    const std::string owner = ownerOf(staged_);
    std::ofstream marker(fs::path(staged_) / kMarker, std::ios::trunc);
    marker << owner << "\n";
    for (const std::string& file : filesUnder(staged_)) marker << file << "\n";
    if (!marker) throw std::runtime_error("cannot write in " + staged_);
  }
  std::string old;
  if (fs::exists(target_)) {
    old = uniqueDirectory(target_ + ".old");
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
  // The rename would put a regular file in place of a device, a pipe or a socket.
  std::error_code ec;
  const fs::file_status status = fs::status(t, ec);
  if (!ec && fs::exists(status) && !fs::is_regular_file(status))
    throw std::runtime_error(target +
                             " exists and is not a regular file (a device, a pipe or a "
                             "socket): give the path of a file");
  target_ = t.string();
  removeStalePartials(t);
  staged_ = stagedStem(t);
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
