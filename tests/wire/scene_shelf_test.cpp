// The scene shelf (wire/scene_shelf.h) and share_bundle_scene: one loaded scene per content hash in a
// process while a user holds it, loaded again once nobody does.
#include "wire/scene_shelf.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>

#include "common/scene_loader.h"
#include "wire/scene_bundle.h"

namespace epr {
namespace {

namespace fs = std::filesystem;

TEST(SceneShelf, HoldsScenesWeaklyAndKeepsTheFirst) {
  const std::string hash = "shelf-test-" + std::to_string(::getpid());
  EXPECT_EQ(shelved_scene(hash), nullptr);
  auto first = std::make_shared<const Scene>(Scene{});
  auto second = std::make_shared<const Scene>(Scene{});
  EXPECT_EQ(shelve_scene(hash, first), first);
  EXPECT_EQ(shelve_scene(hash, second), first) << "a scene shelved while another is held replaced it";
  EXPECT_EQ(shelved_scene(hash), first);
  first.reset();
  EXPECT_EQ(shelved_scene(hash), nullptr) << "the shelf kept a scene nobody holds";
  EXPECT_EQ(shelve_scene(hash, second), second);
}

TEST(SceneShelf, ShareBundleSceneLoadsOnceWhileHeld) {
  const fs::path cache = fs::temp_directory_path() / ("epr-shelf-test-" + std::to_string(::getpid()));
  const std::string spec = std::string(EPR_SOURCE_DIR) + "/scenes/cutout-lattice/cutout-lattice.gltf";
  const SceneBundleData b = bundle_scene(spec);
  ASSERT_NE(b.loaded, nullptr);
  const std::string hash = content_hash(b);
  const uint64_t before = scene_file_loads();
  auto held = share_bundle_scene(b, hash, cache.string());
  auto again = share_bundle_scene(b, hash, cache.string());
  EXPECT_EQ(held, again);
  EXPECT_EQ(scene_file_loads() - before, 1u);
  EXPECT_EQ(held->triangle_count(), b.loaded->triangle_count());
  held.reset();
  again.reset();
  share_bundle_scene(b, hash, cache.string());  // nobody held it: loaded again
  EXPECT_EQ(scene_file_loads() - before, 2u);
  std::error_code ec;
  fs::remove_all(cache, ec);
}

}  // namespace
}  // namespace epr
