// The worker's scene cache on disk (worker/scene_fetch.h): bounded by size with the least recently
// used scenes removed first, and a private temporary folder when the configured one cannot be
// written. Real scenes received with SceneReceiver into real folders.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <thread>

#include "wire/scene_bundle.h"
#include "worker/scene_fetch.h"

namespace epr {
namespace {
namespace fs = std::filesystem;
using namespace std::chrono_literals;

struct TempDir {
  fs::path path;
  TempDir() {
    path = fs::temp_directory_path() / ("epr-scene-cache-" + std::to_string(::getpid()) + "-" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(path);
    fs::create_directories(path);
  }
  ~TempDir() { fs::remove_all(path); }
  std::string str() const { return path.string(); }
};

// Receives a one-file scene of `bytes` bytes (its content named by `tag`) into the cache at `root`,
// as a FetchScene stream would bring it; returns its hash.
std::string cache_scene(const std::string& root, const std::string& tag, size_t bytes) {
  SceneBundleData b;
  b.entry_path = tag + ".obj";
  b.files = {{b.entry_path, "# " + tag + "\n" + std::string(bytes, 'x')}};
  const std::string hash = content_hash(b);
  SceneReceiver rx(root, hash);
  v1::SceneChunk m;
  auto* man = m.mutable_manifest();
  man->set_content_hash(hash);
  man->set_entry_path(b.entry_path);
  man->set_total_bytes(b.total_bytes());
  auto* f = man->add_files();
  f->set_path(b.entry_path);
  f->set_size_bytes(b.files[0].second.size());
  EXPECT_EQ(rx.add(m), std::nullopt);
  v1::SceneChunk d;
  d.mutable_data()->set_file_index(0);
  d.mutable_data()->set_offset(0);
  d.mutable_data()->set_data(b.files[0].second);
  EXPECT_EQ(rx.add(d), std::nullopt);
  std::string entry;
  EXPECT_EQ(rx.finish(&entry), std::nullopt);
  return hash;
}

// Sets when a cached scene was last used, `age` ago.
void used_ago(const std::string& root, const std::string& hash, std::chrono::seconds age) {
  fs::last_write_time(fs::path(root) / "scenes" / hash / ".complete", fs::file_time_type::clock::now() - age);
}

bool cached(const std::string& root, const std::string& hash) { return cached_scene_entry(root, hash).has_value(); }

TEST(SceneCache, LeastRecentlyUsedScenesGoFirstOverTheBound) {
  TempDir dir;
  const std::string root = dir.str();
  const std::string a = cache_scene(root, "a", 100'000);
  const std::string b = cache_scene(root, "b", 100'000);
  const std::string c = cache_scene(root, "c", 100'000);
  used_ago(root, a, 300s);
  used_ago(root, b, 200s);
  used_ago(root, c, 100s);

  // Within the bound: nothing goes.
  EXPECT_TRUE(trim_scene_cache(root, 1'000'000).empty());
  // Room for two of the three: the least recently used one goes, with all its files.
  EXPECT_EQ(trim_scene_cache(root, 250'000), std::vector<std::string>{a});
  EXPECT_FALSE(fs::exists(fs::path(root) / "scenes" / a));
  EXPECT_TRUE(cached(root, b));
  EXPECT_TRUE(cached(root, c));

  // A job loads b again: it is now the most recently used, so c goes when d arrives.
  touch_cached_scene(root, b);
  const std::string d = cache_scene(root, "d", 100'000);
  EXPECT_EQ(trim_scene_cache(root, 250'000, d), std::vector<std::string>{c});
  EXPECT_TRUE(cached(root, b));
  EXPECT_TRUE(cached(root, d));
  EXPECT_EQ(cached_scene_hashes(root).size(), 2u);

  // The scene a job is about to load stays even when it alone is over the bound.
  used_ago(root, d, 500s);
  EXPECT_EQ(trim_scene_cache(root, 1, d), std::vector<std::string>{b});
  EXPECT_TRUE(cached(root, d));
}

TEST(SceneCache, UnwritableFolderFallsBackToAPrivateOneRemovedAtTheEnd) {
  TempDir dir;
  {
    const CacheRoot usable(dir.str() + "/cache");
    EXPECT_EQ(usable.path(), dir.str() + "/cache");
    EXPECT_TRUE(usable.fallback_reason().empty()) << usable.fallback_reason();
    EXPECT_TRUE(fs::is_directory(usable.path() + "/scenes"));
  }
  EXPECT_TRUE(fs::is_directory(dir.str() + "/cache")) << "a configured cache outlives the worker";

  std::string fallback;
  {
    // Below a regular file nothing can be created, not even by root (permissions would not stop it).
    std::ofstream(dir.path / "file") << "x";
    const CacheRoot root((dir.path / "file" / "cache").string());
    fallback = root.path();
    EXPECT_NE(root.fallback_reason().find((dir.path / "file").string()), std::string::npos) << root.fallback_reason();
    EXPECT_NE(fallback.find("epr-worker-cache-"), std::string::npos) << fallback;
    // It works as a cache.
    const std::string h = cache_scene(fallback, "a", 10);
    EXPECT_TRUE(cached(fallback, h));
  }
  EXPECT_FALSE(fs::exists(fallback)) << "the private cache is removed with its CacheRoot";
}

}  // namespace
}  // namespace epr
