// The preview PNGs of large frames over real HTTP (loopback) against an in-process master driven by a
// hand-driven worker: a frame larger than the bound (1024 px on its longest side by default, ?max=N)
// previews downscaled by a whole factor, keeping its aspect ratio, and each preview pixel is the
// box-filtered mean of the full-resolution image that `epr get --partial` (the job's partial result,
// from the same round's copy) or the finished job's result files hold, within 8-bit rounding; a frame
// within the bound keeps its full resolution.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "common/image.h"
#include "common/result_kinds.h"
#include "monitoring_helpers.h"

namespace epr::monitoring_test {
namespace {

float linear_to_srgb(float c) {
  c = std::clamp(c, 0.f, 1.f);
  return c <= 0.0031308f ? 12.92f * c : 1.055f * std::pow(c, 1 / 2.4f) - 0.055f;
}
int srgb8(float linear) { return int(std::lround(linear_to_srgb(std::isfinite(linear) ? linear : 0.f) * 255.f)); }

// The test's own box filter: block (bx, by) of k x k pixels (clipped at the edges), mean per channel.
Image box_mean(const Image& img, int k) {
  Image out((img.width + k - 1) / k, (img.height + k - 1) / k, img.channels);
  for (int by = 0; by < out.height; ++by)
    for (int bx = 0; bx < out.width; ++bx)
      for (int c = 0; c < img.channels; ++c) {
        double sum = 0;
        int n = 0;
        for (int y = by * k; y < std::min(img.height, (by + 1) * k); ++y)
          for (int x = bx * k; x < std::min(img.width, (bx + 1) * k); ++x, ++n) sum += img.at(x, y)[c];
        out.at(bx, by)[c] = float(sum / n);
      }
  return out;
}

Image decode(const std::string& bytes, const fs::path& file) {
  std::ofstream(file, std::ios::binary) << bytes;
  return read_image(file.string());  // 8-bit sRGB, linearised by OpenImageIO: srgb8() recovers the bytes
}

// Every pixel of `png` (a decoded preview) against the expected linear image, in 8-bit sRGB.
void expect_pixels_equal(const Image& png, const Image& expected, const std::string& what) {
  ASSERT_EQ(png.width, expected.width) << what;
  ASSERT_EQ(png.height, expected.height) << what;
  ASSERT_EQ(png.channels, 3) << what;
  int worst = 0, off = 0;
  for (int y = 0; y < png.height; ++y)
    for (int x = 0; x < png.width; ++x)
      for (int c = 0; c < 3; ++c) {
        const float e = expected.channels >= 3 ? expected.at(x, y)[c] : expected.at(x, y)[0];
        const int d = std::abs(srgb8(png.at(x, y)[c]) - srgb8(e));
        worst = std::max(worst, d);
        off += d > 0;
      }
  EXPECT_LE(worst, 1) << what << ": the preview is not the box-filtered image (" << off << " channel values differ)";
}

class MonitoringPreviewTest : public ::testing::Test {
 protected:
  void SetUp() override {
    master_ = start_master();
    client_ = std::make_unique<JobClient>(master_->local_target());
    worker_ = std::make_unique<ManualWorker>(master_->local_target());
  }
  void TearDown() override { master_->shutdown(); }

  // GET image.png of `layer` (with `query` appended); the PNG bytes, failing the test otherwise.
  std::string preview(const std::string& id, const std::string& layer, const std::string& query = "",
                      std::string* image_size = nullptr) {
    auto http = http_client(*master_);
    auto r = http.Get(("/api/v1/jobs/" + id + "/image.png?layer=" + layer + query).c_str());
    if (!r) {
      ADD_FAILURE() << "GET failed: " << httplib::to_string(r.error());
      return "";
    }
    EXPECT_EQ(r->status, 200) << layer << query << ": " << r->body;
    EXPECT_EQ(r->get_header_value("Content-Type"), "image/png");
    if (image_size) *image_size = r->get_header_value("X-Image-Size");
    return r->body;
  }
  // The full-resolution image of `kind` the job's (partial) results hold.
  Image full_image(const std::string& id, ResultKind kind, const fs::path& file) {
    auto f = master_->jobs().result_file(id, kind, /*allow_partial=*/true);
    EXPECT_EQ(f.error, JobManager::ResultFile::Error::kNone) << f.why;
    return decode(f.bytes, file);
  }
  // Closes rounds until the job has a preview.
  void close_first_round(const std::string& id) {
    ASSERT_TRUE(wait_for([&] { return master_->jobs().get(id)->state == JobState::kRunning; }, 60));
    ASSERT_GT(worker_->work_available(), 0);
    ASSERT_TRUE(wait_for([&] { return master_->jobs().preview_png(id, "combined").has_value(); }, 60))
        << "no preview after the first round";
  }
  // Every layer at `query` against the box-filtered full-resolution results.
  void check_layers(const std::string& id, const RenderOptions& o, const std::string& query, int k,
                    const fs::path& dir) {
    const std::pair<uint32_t, uint32_t> want{uint32_t((o.width + k - 1) / k), uint32_t((o.height + k - 1) / k)};
    struct Layer {
      std::string name;
      ResultKind kind;
    };
    for (const Layer& l :
         {Layer{"combined", ResultKind::kExr}, Layer{"pathtrace", ResultKind::kPathtrace},
          Layer{"reprojection", ResultKind::kReprojection}, Layer{"samples", ResultKind::kSamplesExr}}) {
      SCOPED_TRACE(l.name + query);
      std::string size;
      const std::string png = preview(id, l.name, query, &size);
      EXPECT_EQ(png_size(png), want);
      EXPECT_EQ(size, std::to_string(o.width) + "x" + std::to_string(o.height));
      const Image full = full_image(id, l.kind, dir / (l.name + ".exr"));
      ASSERT_EQ(full.width, o.width);
      Image expected = box_mean(full, k);
      if (l.name == "samples") {  // the heat map of the mean M', coloured against the image's largest M'
        const float max_m = *std::max_element(full.data.begin(), full.data.end());
        ASSERT_GT(max_m, 0.f);
        expected = heat_map(expected, max_m);
      }
      expect_pixels_equal(decode(png, dir / (l.name + ".png")), expected, l.name + query);
    }
  }

  std::unique_ptr<MasterServer> master_;
  std::unique_ptr<JobClient> client_;
  std::unique_ptr<ManualWorker> worker_;
};

TEST_F(MonitoringPreviewTest, LargeFramesPreviewAsTheBoxFilteredImageWithinTheBound) {
  const fs::path dir = scratch_dir("preview-bound");
  RenderOptions o;
  o.scene = "builtin:cornell";
  o.width = 203;  // not a multiple of the factor: the last column of blocks is 3 pixels wide
  o.height = 120;
  o.spp = 3;
  o.paths_per_round = 1;
  o.mode = RenderMode::kSkip;
  o.tile_size = 64;
  const std::string id = client_->submit(o);
  close_first_round(id);

  // Within the default bound: the full resolution.
  for (const std::string layer : {"combined", "samples"})
    EXPECT_EQ(png_size(preview(id, layer)), std::make_pair(uint32_t(o.width), uint32_t(o.height))) << layer;
  // ?max=64: ceil(203 / 64) = 4, a 51 x 30 preview (the aspect ratio to within a pixel) of 4 x 4 means.
  check_layers(id, o, "&max=64", 4, dir);
  // ?max=100 rounds down to 64: the same preview.
  EXPECT_EQ(preview(id, "combined", "&max=100"), preview(id, "combined", "&max=64"));
  // ?max=128: factor 2.
  check_layers(id, o, "&max=128", 2, dir);

  // A bad bound is refused; an unknown layer still is.
  auto http = http_client(*master_);
  for (const std::string bad : {"0", "-5", "abc", "12px", ""}) {
    const json e = get_json(http, "/api/v1/jobs/" + id + "/image.png?max=" + bad, 400);
    EXPECT_EQ(e["reason"], "bad_max") << bad;
  }

  // Finished: the previews come from the result files, box-filtered the same way.
  ASSERT_TRUE(wait_for(
      [&] {
        worker_->work_available();
        return master_->jobs().get(id)->state == JobState::kDone;
      },
      120));
  check_layers(id, o, "&max=64", 4, dir);
  EXPECT_EQ(png_size(preview(id, "combined")), std::make_pair(uint32_t(o.width), uint32_t(o.height)));
}

TEST_F(MonitoringPreviewTest, DefaultBoundIs1024PixelsOnTheLongestSide) {
  const fs::path dir = scratch_dir("preview-default");
  RenderOptions o;
  o.scene = "builtin:cornell";
  o.width = 1100;  // factor ceil(1100 / 1024) = 2: 550 x 310
  o.height = 620;
  o.spp = 2;
  o.paths_per_round = 1;
  o.mode = RenderMode::kPathTrace;
  o.tile_size = 128;
  const std::string id = client_->submit(o);
  close_first_round(id);

  std::string size;
  const std::string png = preview(id, "combined", "", &size);
  EXPECT_EQ(png_size(png), std::make_pair(550u, 310u));
  EXPECT_EQ(size, "1100x620");
  expect_pixels_equal(decode(png, dir / "combined.png"), box_mean(full_image(id, ResultKind::kExr, dir / "c.exr"), 2),
                      "combined");
  // A larger bound gives the full resolution back.
  EXPECT_EQ(png_size(preview(id, "combined", "&max=2048")), std::make_pair(1100u, 620u));
  EXPECT_EQ(png_size(preview(id, "pathtrace", "&max=1024")), std::make_pair(550u, 310u));
}

}  // namespace
}  // namespace epr::monitoring_test
