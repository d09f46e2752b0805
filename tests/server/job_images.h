// The images of a job a JobManager has finished (M and M', the path-traced estimate, the combined
// image), read from its result files, and their comparison with another run's: for the tests that
// drive a JobManager in the test process (multi_job_test.cpp, checkpoint_test.cpp).
#pragma once

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <utility>

#include "common/image.h"
#include "common/result_kinds.h"
#include "master/server/job_manager.h"

namespace epr::test {

struct JobImages {
  Image counts, pathtrace, combined;
};

/// Job `id`'s result images; each result file must exist.
inline JobImages results_of(JobManager& jobs, const std::string& id) {
  JobImages r;
  for (auto [kind, image] : {std::pair{ResultKind::kCounts, &r.counts},
                             {ResultKind::kPathtrace, &r.pathtrace},
                             {ResultKind::kExr, &r.combined}}) {
    const auto path = jobs.result_path(id, kind);
    EXPECT_TRUE(path) << result_kind(kind).name;
    if (path) *image = read_image(*path);
  }
  return r;
}

/// M, M' and the path-traced sums bit for bit; the combined image within float rounding (the
/// reprojected sums of a round are added in commit order).
inline void expect_same_images(const JobImages& a, const JobImages& b) {
  EXPECT_EQ(a.counts.data, b.counts.data) << "M and M' per pixel";
  EXPECT_EQ(a.pathtrace.data, b.pathtrace.data) << "path-traced estimate";
  ASSERT_EQ(a.combined.data.size(), b.combined.data.size());
  size_t differ = 0;
  for (size_t i = 0; i < a.combined.data.size(); ++i) {
    const float x = a.combined.data[i], y = b.combined.data[i];
    differ += !(std::fabs(x - y) <= 1e-5f + 1e-4f * std::max(std::fabs(x), std::fabs(y)));
  }
  EXPECT_EQ(differ, 0u) << "combined image values beyond float rounding";
}

}  // namespace epr::test
