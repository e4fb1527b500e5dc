#pragma once
/// @file staged_output.h
/// Results written in full or not at all. A staged output is created beside its target at once
/// (so an unusable target fails before any work is done), filled, and put in place of the
/// target by commit(); destroyed without commit() it is removed, and the target keeps what it
/// had. Throws std::runtime_error naming the path on failure.

#include <string>

namespace simstack {

/// Longest name of one file or directory the file systems here take (bytes).
constexpr size_t kMaxFileNameBytes = 255;
/// Why `path` cannot name a file or directory to write, as a sentence naming the limit ("" when
/// it can): empty, holding a control character (a newline, say), a component longer than
/// kMaxFileNameBytes, or the whole longer than 4096 bytes.
std::string unwritablePath(const std::string& path);

/// Whether directory `outer` is `inner` or holds it (both taken absolute and normal, "out/" as
/// "out"): replacing `outer` would remove `inner`.
bool pathHolds(const std::string& outer, const std::string& inner);

/// A directory: commit() replaces the target directory whole, so that no file of an earlier
/// run stays beside the new ones. It holds a marker file (`.simstack-output`) naming `owner`, the
/// tool that wrote it and listing the files it wrote. Refused at construction: an existing
/// non-empty target without that owner's marker (the user's files, another tool's result), one
/// holding files its run did not write (put there since: they would be removed), and one
/// holding the working directory. "out/" is "out".
class StagedDirectory {
 public:
  StagedDirectory(const std::string& target, const std::string& owner);
  ~StagedDirectory();
  StagedDirectory(const StagedDirectory&) = delete;
  StagedDirectory& operator=(const StagedDirectory&) = delete;
  /// Where to write.
  const std::string& path() const { return staged_; }
  void commit();

 private:
  std::string target_, staged_;
  bool committed_ = false;
};

/// One file: commit() renames it onto the target. A target that exists and is not a regular
/// file (a directory, a device, a pipe) is refused at construction.
class StagedFile {
 public:
  explicit StagedFile(const std::string& target);
  ~StagedFile();
  StagedFile(const StagedFile&) = delete;
  StagedFile& operator=(const StagedFile&) = delete;
  const std::string& path() const { return staged_; }
  void commit();

 private:
  std::string target_, staged_;
  bool committed_ = false;
};

}  // namespace simstack
