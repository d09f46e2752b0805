// A master whose disk fills while it writes a job's results: the real epr-master with RLIMIT_FSIZE
// (SIGXFSZ ignored: a write past the limit fails with EFBIG, as a full disk fails with ENOSPC, and
// works as root) and real workers on loopback. The job fails naming the file and the errno; every
// result file under its final name is whole (one that did not fit is not there), no temporary file is
// left behind, and every "cannot" line of the master's log names the errno.
#include <gtest/gtest.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "binaries.h"
#include "common/image.h"
#include "common/result_kinds.h"
#include "farm_steps.h"
#include "process.h"

namespace epr::testing {
namespace {
namespace fs = std::filesystem;
using namespace std::chrono_literals;

// Room for the small files (the PNGs, the zipped counts, the statistics, the logs) but not for an
// uncompressed 256x256 RGB float image (768 KiB).
constexpr uint64_t kFileSizeLimit = 512 << 10;

class FullDiskTest : public SingleMasterTest {
 protected:
  void SetUp() override { start_story("epr-full-disk"); }
};

TEST_F(FullDiskTest, AResultFileThatDoesNotFitIsNotLeftUnderItsName) {
  ProcessOptions po;
  po.file_size_limit = kFileSizeLimit;
  master_ = std::make_unique<Process>(master_argv(0, {"--state-dir", path("state"), "--no-checkpoints"}),
                                      dir_ / "master", po);
  port_ = listening_port(*master_, 30s);
  ASSERT_NE(port_, 0) << master_->err();
  for (const char* name : {"w1", "w2"}) start_worker(name);
  const std::string id = submit(skip_job(256, 8, 8, 8, 5));
  ASSERT_FALSE(HasFailure()) << "epr submit failed";
  note("job %s submitted", id.c_str());

  const RunResult watched = epr({"watch", id}, 180s);
  EXPECT_EQ(watched.code, 1) << "the job must fail: " << watched.out << watched.err;
  const RunResult got = epr({"get", id, "--json"}, 30s);
  ASSERT_EQ(got.code, 0) << got.err;
  const nlohmann::json status = nlohmann::json::parse(got.out, nullptr, false);
  EXPECT_EQ(status.value("state", ""), "JOB_STATE_FAILED") << got.out;
  const std::string efbig = std::strerror(EFBIG);
  EXPECT_NE(status.value("error_message", "").find(efbig), std::string::npos) << got.out;
  EXPECT_TRUE(master_->running()) << master_->err();

  // Every file under a result's name is whole; the one that did not fit is not there.
  const fs::path folder = fs::path(path("state")) / "jobs" / id;
  ASSERT_TRUE(fs::is_directory(folder)) << folder;
  for (const auto& e : fs::directory_iterator(folder))
    EXPECT_NE(e.path().filename().string().rfind(".tmp", 0), 0u) << "left behind: " << e.path();
  int present = 0;
  for (const ResultKindInfo& k : result_kinds()) {
    const fs::path file = folder / k.stored_as;
    if (!fs::exists(file)) continue;
    ++present;
    SCOPED_TRACE(file.string());
    EXPECT_GT(fs::file_size(file), 0u);
    if (k.kind == ResultKind::kJson) {
      EXPECT_FALSE(nlohmann::json::parse(read_text(file), nullptr, false).is_discarded());
      continue;
    }
    try {
      const Image img = read_image(file.string());
      EXPECT_EQ(img.width, 256);
      EXPECT_EQ(img.height, 256);
    } catch (const std::exception& ex) {
      ADD_FAILURE() << "not a whole image: " << ex.what();
    }
  }
  EXPECT_FALSE(fs::exists(folder / result_kind(ResultKind::kExr).stored_as)) << "768 KiB cannot have fit";
  note("%d whole result files of %zu kinds", present, result_kinds().size());

  // Every failure the master logged names the errno.
  std::istringstream log(master_->err());
  int failures = 0;
  for (std::string line; std::getline(log, line);) {
    if (line.find("cannot") == std::string::npos) continue;
    ++failures;
    EXPECT_NE(line.find(efbig), std::string::npos) << line;
  }
  EXPECT_GT(failures, 0);
}

}  // namespace
}  // namespace epr::testing
