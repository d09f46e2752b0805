// A finished render's files on a disk that fills (tests/file_size_limit.h): write_results throws
// naming the file and the errno, and leaves no file under a result's name, nor a temporary one; with
// room, every kind is written whole.
#include "master/result_files.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <string>

#include "common/image.h"
#include "tests/file_size_limit.h"

namespace epr::test {
namespace {
namespace fs = std::filesystem;

class ResultFilesTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::path(::testing::TempDir()) / ("epr-result-files-" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    // 64x64 pixels of a reprojecting frame, with values that vary (so that nothing compresses away).
    images_.path_sum = Image(64, 64, 3);
    images_.reprojection = Image(64, 64, 3);
    images_.path_count = Image(64, 64, 1);
    images_.reprojected = Image(64, 64, 1);
    for (size_t i = 0; i < images_.path_sum.data.size(); ++i) {
      images_.path_sum.data[i] = float(i % 97) / 7.f;
      images_.reprojection.data[i] = float(i % 89) / 89.f;
    }
    for (size_t i = 0; i < images_.path_count.data.size(); ++i) {
      images_.path_count.data[i] = float(1 + i % 5);
      images_.reprojected.data[i] = float(i % 13);
    }
  }
  void TearDown() override { fs::remove_all(dir_); }

  void write() {
    write_results(images_, /*reprojects=*/true, {{"rounds", 1}},
                  [&](const ResultKindInfo& k) { return (dir_ / k.stored_as).string(); });
  }

  fs::path dir_;
  FrameImages images_;
};

TEST_F(ResultFilesTest, AFullDiskLeavesNoFileUnderAResultsName) {
  std::string error;
  {
    FileSizeLimit limit(0);  // no byte fits
    try {
      write();
    } catch (const std::exception& e) {
      error = e.what();
    }
  }
  EXPECT_NE(error.find(std::strerror(EFBIG)), std::string::npos) << error;
  EXPECT_NE(error.find(dir_.string()), std::string::npos) << "the file is named: " << error;
  for (const auto& e : fs::directory_iterator(dir_)) ADD_FAILURE() << "left behind: " << e.path();
}

TEST_F(ResultFilesTest, WithRoomEveryKindIsWrittenWhole) {
  write();
  for (const ResultKindInfo& k : result_kinds()) {
    const fs::path file = dir_ / k.stored_as;
    ASSERT_TRUE(fs::exists(file)) << file;
    if (k.kind == ResultKind::kJson) continue;
    const Image img = read_image(file.string());
    EXPECT_EQ(img.width, 64) << file;
    EXPECT_EQ(img.height, 64) << file;
  }
  for (const auto& e : fs::directory_iterator(dir_))
    EXPECT_NE(e.path().filename().string().rfind(".tmp", 0), 0u) << "left behind: " << e.path();
}

}  // namespace
}  // namespace epr::test
