// libFuzzer target for the depth readers (readDepthPcd, readDepthImage): the first byte picks
// the format (.pcd, .png, .tiff), the rest is the file. A reader may refuse the file with an
// exception; it must not crash, hang or allocate without bound. Built and run by
// test/fuzz/run_fuzz.sh (clang's libFuzzer).
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <exception>
#include <fstream>
#include <string>

#include "simstack/io/image_io.h"
#include "simstack/io/scene_io.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const std::string base = "/tmp/simstack_fuzz_" + std::to_string(getpid());
  if (size == 0) return 0;
  static const char* const kExtensions[] = {".pcd", ".png", ".tiff"};
  const int kind = data[0] % 3;
  const std::string path = base + kExtensions[kind];
  {
    std::ofstream f(path, std::ios::binary);
    f.write(reinterpret_cast<const char*>(data + 1), static_cast<std::streamsize>(size - 1));
  }
  try {
    if (kind == 0)
      simstack::readDepthPcd(path);
    else
      simstack::readDepthImage(path, 0.001);
  } catch (const std::exception&) {
    // refused: what a reader must do with a bad file
  }
  std::remove(path.c_str());
  return 0;
}
