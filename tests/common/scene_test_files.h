// Helpers of the scene loader tests: a scene folder of their own per test, and the error of a load.
#pragma once

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "common/scene_loader.h"

namespace epr::test {

/// Three OBJ vertices spanning one triangle (`f 1 2 3`), for the scene files the tests write.
inline const std::string kTriangle = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";

/// A fresh folder per test, removed afterwards.
class TempDir {
 public:
  TempDir() {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    root_ = std::filesystem::temp_directory_path() /
            fmt::format("epr_scene_{}_{}_{}", info->test_suite_name(), info->name(), getpid());
    std::filesystem::remove_all(root_);
    std::filesystem::create_directories(root_);
  }
  ~TempDir() {
    std::error_code ec;
    std::filesystem::remove_all(root_, ec);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;

  std::string path(const std::string& rel) const { return (root_ / rel).string(); }
  /// Writes `text` to the file `rel` (creating its folders) and returns its path.
  std::string write(const std::string& rel, const std::string& text) const {
    const std::filesystem::path p = root_ / rel;
    std::filesystem::create_directories(p.parent_path());
    std::ofstream(p, std::ios::binary) << text;
    return p.string();
  }

 private:
  std::filesystem::path root_;
};

/// The SceneError message of loading `spec`, or "" if it loaded. Any other exception fails the test.
inline std::string load_error(const std::string& spec, const LoadOptions& opts = {}) {
  try {
    load_scene(spec, opts);
  } catch (const SceneError& e) {
    return e.what();
  }
  return "";
}

}  // namespace epr::test
