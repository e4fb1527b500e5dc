#include <gtest/gtest.h>

#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>
#include <utility>
#include <vector>

#include <H5Cpp.h>

#include "simstack/io/staged_output.h"
#include "simstack/offline/dataset/dataset.h"
#include "simstack/offline/piles/household.h"
#include "simstack/offline/piles/pile_generator.h"
#include "test_scenes.h"

using namespace simstack;

namespace {
/// A small dataset's header: `scenes` piles on a 16^3 grid of 0.64 m.
DatasetInfo smallInfo(int scenes) {
  DatasetInfo info;
  info.num_scenes = scenes;
  info.resolution = 16;
  info.extent_m = 0.64;
  info.truncation_m = 0.12;
  return info;
}
}  // namespace

TEST(Dataset, WriteReadRoundTrip) {
  const std::string path = test::tempPath("simstack_test_dataset.h5").string();
  const PileGenerator gen{PileConfig()};
  DatasetInfo info = smallInfo(3);
  info.seed = 77;
  std::vector<Scene> scenes;
  std::vector<GroundTruthGrids> gts;
  {
    DatasetWriter writer(path, info);
    for (int i = 2; i >= 0; --i) {  // any order
      const Scene s = gen.generate(100 + i).scene;
      const GridSpec g =
          GridSpec::sceneGrid(s.surfaceCentroid().head<2>(), info.extent_m, info.resolution);
      writer.write(i, s, computeGroundTruth(s, g, info.truncation_m));
    }
  }
  const DatasetReader reader(path);
  EXPECT_EQ(reader.size(), 3);
  EXPECT_EQ(reader.info().resolution, 16);
  EXPECT_EQ(reader.info().seed, 77u);
  EXPECT_EQ(reader.info().generator_version, kGeneratorVersion);
  for (int i = 0; i < 3; ++i) {
    const Scene s = gen.generate(100 + i).scene;
    const GridSpec g =
        GridSpec::sceneGrid(s.surfaceCentroid().head<2>(), info.extent_m, info.resolution);
    const GroundTruthGrids gt = computeGroundTruth(s, g, info.truncation_m);
    const SceneRecord rec = reader.read(i);
    ASSERT_EQ(rec.scene.objects.size(), s.objects.size());
    EXPECT_TRUE(rec.grid == g);
    for (size_t k = 0; k < s.objects.size(); ++k) {
      EXPECT_TRUE(rec.scene.objects[k].T_table_object.isApprox(s.objects[k].T_table_object, 1e-12));
      EXPECT_EQ(rec.scene.objects[k].shape->superquadric().scale_m,
                s.objects[k].shape->superquadric().scale_m);
      EXPECT_EQ(rec.scene.objects[k].shape->superquadric().exponents,
                s.objects[k].shape->superquadric().exponents);
    }
    EXPECT_EQ(rec.ground_truth.tsdf.data, gt.tsdf.data);
    EXPECT_EQ(rec.ground_truth.labels.data, gt.labels.data);
    for (size_t v = 0; v < gt.votes.data.size(); ++v)
      ASSERT_EQ(rec.ground_truth.votes.data[v], gt.votes.data[v]);
  }
  EXPECT_THROW(reader.read(3), std::out_of_range);
  std::filesystem::remove(path);
}

TEST(Dataset, HouseholdPilesRebuildTheirContainersWithoutAMeshDirectory) {
  const std::string path = test::tempPath("simstack_test_household.h5").string();
  PileConfig config;
  config.household_share = 1.0;
  config.require_stack = false;
  const PileGenerator gen{config};
  DatasetInfo info = smallInfo(1);
  for (const auto& c : containerCatalogue()) info.mesh_names.push_back(c->name());
  Scene scene;
  for (uint64_t seed = 1; scene.objects.empty() && seed < 40; ++seed) {
    const Scene s = gen.generate(seed).scene;
    for (const auto& o : s.objects)
      if (o.shape->kind() == ObjectShape::Kind::kMesh) scene = s;
  }
  ASSERT_FALSE(scene.objects.empty()) << "no pile with a container in 40 seeds";
  const GridSpec g =
      GridSpec::sceneGrid(scene.surfaceCentroid().head<2>(), info.extent_m, info.resolution);
  const GroundTruthGrids gt = computeGroundTruth(scene, g, info.truncation_m);
  {
    DatasetWriter writer(path, info);
    writer.write(0, scene, gt);
  }
  const SceneRecord rec = DatasetReader(path).read(0);
  ASSERT_EQ(rec.scene.objects.size(), scene.objects.size());
  for (size_t k = 0; k < scene.objects.size(); ++k)
    EXPECT_EQ(rec.scene.objects[k].shape->name(), scene.objects[k].shape->name());
  EXPECT_EQ(computeGroundTruth(rec.scene, g, info.truncation_m).tsdf.data, gt.tsdf.data);
  std::filesystem::remove(path);
}

// Several files read as one: scenes interleaved in proportion to the files' sizes, so the
// tail of the mix (a training's validation scenes) holds each file's last scenes.
TEST(Dataset, AMixInterleavesItsFilesInProportionAndRefusesOtherGrids) {
  const auto dir = test::tempPath("");
  const std::string a = (dir / "simstack_test_mix_a.h5").string();
  const std::string b = (dir / "simstack_test_mix_b.h5").string();
  const std::string c = (dir / "simstack_test_mix_c.h5").string();
  const PileGenerator gen{PileConfig()};
  const auto write = [&](const std::string& path, DatasetInfo info, uint64_t first_seed) {
    DatasetWriter writer(path, info);
    for (int i = 0; i < info.num_scenes; ++i) {
      const Scene s = gen.generate(first_seed + i).scene;
      const GridSpec g =
          GridSpec::sceneGrid(s.surfaceCentroid().head<2>(), info.extent_m, info.resolution);
      writer.write(i, s, computeGroundTruth(s, g, info.truncation_m));
    }
  };
  write(a, smallInfo(2), 200);
  write(b, smallInfo(4), 300);
  DatasetInfo coarse = smallInfo(1);
  coarse.resolution = 8;
  write(c, coarse, 400);

  const DatasetMix mix({a, b});
  ASSERT_EQ(mix.size(), 6);
  EXPECT_EQ(mix.name(), a + " + " + b);
  const std::vector<std::pair<int, int>> order = {{0, 0}, {1, 0}, {1, 1}, {0, 1}, {1, 2}, {1, 3}};
  for (int i = 0; i < 6; ++i) {
    EXPECT_EQ(mix.locate(i), order[i]) << "scene " << i;
    const auto [k, j] = order[i];
    EXPECT_EQ(mix.read(i).ground_truth.tsdf.data, mix.file(k).read(j).ground_truth.tsdf.data);
  }
  // The last three: one of a's two scenes, two of b's four.
  EXPECT_EQ(mix.locate(3).first + mix.locate(4).first + mix.locate(5).first, 2);
  EXPECT_THROW(mix.read(6), std::out_of_range);
  // One file is itself, scene for scene.
  const DatasetMix one({b});
  for (int i = 0; i < 4; ++i) EXPECT_EQ(one.locate(i), std::make_pair(0, i));
  // Files of other grids cannot be one training's: the message names the odd file.
  try {
    DatasetMix({a, c});
    ADD_FAILURE() << "a mix of 16^3 and 8^3 grids was accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("dataset " + c + " has 8^3 grids"), std::string::npos)
        << e.what();
  }
  // One file twice (or two of one seed's piles): its validation piles would be trained on.
  ASSERT_EQ(mix.file(0).info().seed, mix.file(1).info().seed);  // told apart by their piles
  try {
    DatasetMix({a, b, b});
    ADD_FAILURE() << "a mix of one file twice was accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("datasets " + b + " and " + b + " hold the same piles"),
              std::string::npos)
        << e.what();
  }
  EXPECT_THROW(DatasetMix({}), std::invalid_argument);
  for (const auto& p : {a, b, c}) std::filesystem::remove(p);
}

TEST(Dataset, ClearErrorsNameTheFile) {
  try {
    DatasetReader reader("/nonexistent/simstack.h5");
    FAIL() << "opening a missing file must throw";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/simstack.h5"), std::string::npos)
        << e.what();
  }
  const std::string path = test::tempPath("simstack_not_hdf5.h5").string();
  { std::ofstream(path) << "not a dataset"; }
  EXPECT_THROW(DatasetReader{path}, std::runtime_error);
  std::filesystem::remove(path);
}

// A file whose attributes disagree with its arrays' shapes (hand-edited, or written by another
// tool) is refused when opened, naming what disagrees, before any read could overrun a buffer.
TEST(Dataset, ArraysThatDisagreeWithTheAttributesAreRefused) {
  const std::string path = test::tempPath("simstack_test_dataset_shapes.h5").string();
  DatasetInfo info = smallInfo(1);
  info.max_objects_per_scene = 4;
  const auto rewrite = [&](const char* name, auto value) {
    {
      DatasetWriter writer(path, info);
      const Scene s = PileGenerator{PileConfig()}.generate(5).scene;
      const GridSpec g = GridSpec::sceneGrid(s.surfaceCentroid().head<2>(), 0.64, 16);
      writer.write(0, s, computeGroundTruth(s, g, info.truncation_m));
    }
    H5::H5File file(path, H5F_ACC_RDWR);
    H5::Attribute attribute = file.openGroup("/").openAttribute(name);
    attribute.write(attribute.getDataType(), &value);
  };
  const auto expectRefused = [&](const std::string& words) {
    try {
      DatasetReader reader(path);
      ADD_FAILURE() << "opened a file whose " << words;
    } catch (const std::runtime_error& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find(path), std::string::npos) << what;
      EXPECT_NE(what.find(words), std::string::npos) << what;
    }
  };
  rewrite("max_objects_per_scene", int64_t{2});
  expectRefused("objects has shape [1, 4, 15], expected [1, 2, 15]");
  rewrite("resolution", int64_t{8});
  expectRefused("tsdf has shape [1, 16, 16, 16], expected [1, 8, 8, 8]");
  rewrite("extent_m", 0.0);
  expectRefused("extent_m");
  rewrite("truncation_m", std::nan(""));
  expectRefused("truncation_m");
  rewrite("max_objects_per_scene", int64_t{4});
  EXPECT_EQ(DatasetReader(path).read(0).grid.resolution, 16);
  std::filesystem::remove(path);
}

TEST(StagedOutput, ACommittedFileReplacesTheTargetAndAnAbandonedOneLeavesNoTrace) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / ("simstack_staged_" + std::to_string(getpid()));
  fs::remove_all(dir);
  const std::string target = (dir / "sub" / "data.h5").string();
  {
    StagedFile staged(target);  // makes the directory, probes the place
    std::ofstream(staged.path()) << "partial";
  }
  EXPECT_FALSE(fs::exists(target));
  EXPECT_EQ(std::distance(fs::directory_iterator(dir / "sub"), fs::directory_iterator()), 0);
  {
    StagedFile staged(target);
    std::ofstream(staged.path()) << "complete";
    staged.commit();
  }
  std::string text;
  std::ifstream(target) >> text;
  EXPECT_EQ(text, "complete");
  // A directory: commit replaces the same tool's earlier result whole; "out/" is "out".
  const std::string out = (dir / "out").string();
  {
    StagedDirectory staged(out + "/", "tool_a");
    std::ofstream(staged.path() + "/stale.ply") << "old";
    staged.commit();
  }
  EXPECT_TRUE(fs::exists(out + "/stale.ply"));
  {
    StagedDirectory staged(out, "tool_a");
    std::ofstream(staged.path() + "/new.yaml") << "new";
    staged.commit();
  }
  EXPECT_TRUE(fs::exists(out + "/new.yaml"));
  EXPECT_FALSE(fs::exists(out + "/stale.ply"));
  // A result directory has the permissions of any directory the user makes (0777 less the
  // umask), not the private ones of a temporary directory.
  const mode_t mask = ::umask(0);
  ::umask(mask);
  EXPECT_EQ(fs::status(out).permissions() & fs::perms::all, static_cast<fs::perms>(0777 & ~mask));
  {
    StagedDirectory staged(out, "tool_a");  // abandoned: the committed one stays
    std::ofstream(staged.path() + "/other.yaml") << "x";
  }
  EXPECT_TRUE(fs::exists(out + "/new.yaml"));
  EXPECT_FALSE(fs::exists(out + "/other.yaml"));
  EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator()), 2);  // sub, out
  EXPECT_THROW(StagedDirectory((dir / "sub" / "data.h5" / "x").string(), "tool_a"),
               std::runtime_error);
  // Never the user's own files, nor another tool's result.
  const std::string mine = (dir / "mine").string();
  fs::create_directories(mine);
  std::ofstream(mine + "/notes.txt") << "mine";
  EXPECT_THROW(StagedDirectory(mine, "tool_a"), std::runtime_error);
  EXPECT_THROW(StagedDirectory(out, "tool_b"), std::runtime_error);
  EXPECT_TRUE(fs::exists(mine + "/notes.txt"));
  EXPECT_TRUE(fs::exists(out + "/new.yaml"));
  // Nor a file put into an earlier result since (a run's own input kept there), in a subdirectory
  // too; once it is moved out, the result is replaced again.
  for (const std::string& added : {out + "/my_depth.png", out + "/sub/notes.txt"}) {
    fs::create_directories(fs::path(added).parent_path());
    std::ofstream(added) << "mine";
    try {
      StagedDirectory staged(out, "tool_a");
      ADD_FAILURE() << "replaces " << out << " holding " << added;
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find(fs::path(added).lexically_relative(out).string()),
                std::string::npos)
          << e.what();
    }
    EXPECT_TRUE(fs::exists(added));
    fs::remove(added);
  }
  EXPECT_NO_THROW(StagedDirectory(out, "tool_a"));
  fs::create_directories(dir / "empty");
  EXPECT_NO_THROW(StagedDirectory((dir / "empty").string(), "tool_a"));
  // Nor the working directory, or one holding it, even an earlier result of the same tool:
  // the caller would be left in a deleted one.
  const fs::path was = fs::current_path();
  fs::create_directories(out + "/sub");  // a directory, no file: not a user's file added
  for (const fs::path& cwd : {fs::path(out), fs::path(out) / "sub"}) {
    fs::current_path(cwd);
    for (const std::string& target : {std::string("."), out}) {
      try {
        StagedDirectory staged(target, "tool_a");
        ADD_FAILURE() << "replaces " << target << " from " << cwd;
      } catch (const std::runtime_error& e) {
        EXPECT_NE(std::string(e.what()).find("is the working directory or holds it"),
                  std::string::npos)
            << e.what();
      }
    }
    fs::current_path(was);
  }
  // A working directory of the user's files: the same reason, not "is not empty".
  fs::create_directories(dir / "users");
  std::ofstream(dir / "users" / "notes.txt") << "mine\n";
  fs::current_path(dir / "users");
  try {
    StagedDirectory staged(".", "tool_a");
    ADD_FAILURE() << "replaces a working directory of the user's files";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find(". is the working directory or holds it"),
              std::string::npos)
        << e.what();
  }
  fs::current_path(was);
  EXPECT_NO_THROW(StagedDirectory(out, "tool_a"));
  fs::remove_all(dir);
}

TEST(StagedOutput, WhatAKilledRunLeftIsRemovedByTheNextOne) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / ("simstack_killed_" + std::to_string(getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  // A process that has ended (as one killed with SIGKILL), and one that runs (this test's
  // parent), each with a staged file and directory left beside the targets.
  const pid_t child = fork();
  if (child == 0) _exit(0);
  ASSERT_GT(child, 0);
  waitpid(child, nullptr, 0);
  char host[256] = {};
  gethostname(host, sizeof(host) - 1);
  const auto left = [&](const std::string& target, pid_t pid, const std::string& tail) {
    const fs::path p = dir / (target + ".partial-" + host + "-" + std::to_string(pid) + tail);
    if (tail.empty())
      std::ofstream(p) << "half";
    else
      fs::create_directories(p / "views");
    return p;
  };
  const fs::path dead_file = left("data.h5", child, ""), live_file = left("data.h5", getppid(), "");
  const fs::path dead_dir = left("out", child, "-a1B2c3"),
                 live_dir = left("out", getppid(), "-d4E5f6");
  const fs::path other_host = dir / "data.h5.partial-elsewhere-1";
  std::ofstream(other_host) << "theirs";
  {
    StagedFile staged((dir / "data.h5").string());
    StagedDirectory staged_dir((dir / "out").string(), "tool_a");
  }
  EXPECT_FALSE(fs::exists(dead_file));
  EXPECT_FALSE(fs::exists(dead_dir));
  EXPECT_TRUE(fs::exists(live_file)) << "a live process's staged file was removed";
  EXPECT_TRUE(fs::exists(live_dir));
  EXPECT_TRUE(fs::exists(other_host)) << "another host's staged file was removed";
  fs::remove_all(dir);
}
