// The scene shelf (wire/scene_shelf.h) and share_bundle_scene: one loaded scene per content hash in a
// process while a user holds it, loaded again once nobody does.
#include "wire/scene_shelf.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>

#include "common/embree_bvh.h"
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

TEST(SceneShelf, AShelvedScenesBvhIsOneObjectBuiltOnceWhileTheSceneIsHeld) {
  const std::string hash = "shelf-bvh-test-" + std::to_string(::getpid());
  Scene box;
  add_quad(box, {-1, -1, 0}, {1, -1, 0}, {1, 1, 0}, {-1, 1, 0}, add_material(box, Material{}));
  std::shared_ptr<const Scene> held = shelve_scene(hash, std::make_shared<const Scene>(box));
  const uint64_t before = embree_bvh_builds();
  const EmbreeBvh* first = &shelved_bvh(held)->bvh();  // the holder goes; the scene held keeps it
  EXPECT_EQ(&shelved_bvh(shelved_scene(hash))->bvh(), first) << "another user of the scene got another BVH";
  EXPECT_EQ(embree_bvh_builds() - before, 1u);
  Hit hit;
  EXPECT_TRUE(first->intersect(Ray{{0, 0, 1}, {0, 0, -1}}, 0, 2, &hit)) << "the BVH is the scene's";
  // A scene not on the shelf gets a BVH of its own each time.
  const auto other = std::make_shared<const Scene>(box);
  EXPECT_NE(shelved_bvh(other), shelved_bvh(other));
  held.reset();
  EXPECT_EQ(shelved_scene(hash), nullptr) << "the BVH kept its scene on the shelf after its last user";
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
