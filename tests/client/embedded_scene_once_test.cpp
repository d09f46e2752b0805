// The embedded render loads a file scene once per process: the scene the client loads to check and
// bundle it is the one the in-process master checks and frames and the in-process workers trace
// (wire/scene_shelf.h), and the image is still the single-process reference's, bit for bit.
#include <gtest/gtest.h>
#include <stdlib.h>
#include <unistd.h>

#include <filesystem>

#include "client/embedded_render.h"
#include "client/local_render.h"
#include "common/embree_bvh.h"
#include "common/image.h"
#include "common/scene_loader.h"

namespace epr {
namespace {

namespace fs = std::filesystem;

TEST(EmbeddedSceneOnce, ClientMasterAndWorkersShareOneLoad) {
  const fs::path dir = fs::temp_directory_path() / ("epr-scene-once-" + std::to_string(::getpid()));
  fs::create_directories(dir);
  // The workers' scene cache in this test's folder: a worker that fetched the scene would write there.
  ::setenv("EPR_CACHE_DIR", (dir / "cache").c_str(), 1);
  RenderOptions o;
  o.scene = std::string(EPR_SOURCE_DIR) + "/scenes/cutout-lattice/cutout-lattice.gltf";  // textures and masks
  o.width = 48;
  o.height = 32;
  o.spp = 4;
  o.tile_size = 16;
  o.seed = 5;
  o.out = (dir / "embedded").string();
  EmbeddedOptions eo;
  eo.workers = 2;  // two worker nodes in this process: both take the shared scene
  eo.worker_threads = 1;
  eo.http_listen = "";
  eo.upload_progress = {};

  const uint64_t before = scene_file_loads(), bvhs_before = embree_bvh_builds();
  const EmbeddedResult r = render_embedded(o, eo);
  const uint64_t loads = scene_file_loads() - before, bvhs = embree_bvh_builds() - bvhs_before;
  ASSERT_EQ(r.status.state(), v1::JOB_STATE_DONE) << r.status.error_message();
  EXPECT_EQ(loads, 1u) << "the embedded render parsed the scene and decoded its textures " << loads << " times";
  // The workers' tracing and the master's edge pixels share the shelved scene's BVH.
  EXPECT_EQ(bvhs, 1u) << "the embedded render built " << bvhs << " BVHs of the scene";
  size_t fetched = 0;  // scenes/HASH folders a worker wrote
  for (const auto& e : fs::directory_iterator(dir / "cache" / "scenes"))
    if (e.path().filename().string().front() != '.') ++fetched;
  EXPECT_EQ(fetched, 0u) << "a worker fetched the scene it could share";

  const Image embedded = read_image(o.out + ".exr", false);
  const Image reference = render_local(o).combined;
  ASSERT_EQ(embedded.width, reference.width);
  ASSERT_EQ(embedded.height, reference.height);
  size_t differ = 0;
  for (int y = 0; y < reference.height; ++y)
    for (int x = 0; x < reference.width; ++x)
      if (!(embedded.rgb(x, y) == reference.rgb(x, y))) ++differ;
  EXPECT_EQ(differ, 0u) << "pixels where the embedded render differs from the single-process one";
  ::unsetenv("EPR_CACHE_DIR");
  std::error_code ec;
  fs::remove_all(dir, ec);
}

}  // namespace
}  // namespace epr
