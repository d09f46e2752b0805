// The worker's scene cache: a FetchScene stream of a real scene lands in the load_bundle layout with
// the right content hash and loads; every malformed stream is refused and leaves nothing behind;
// concurrent fetches of one scene in one process do not collide.
#include "worker/scene_fetch.h"

#include <gtest/gtest.h>
#include <sys/resource.h>

#include <cerrno>
#include <csignal>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <thread>

#include "common/scene_loader.h"
#include "wire/scene_bundle.h"

namespace epr {
namespace {
namespace fs = std::filesystem;

const std::string kCornellObj = EPR_SOURCE_DIR "/scenes/cornell-box/CornellBox-Original.obj";

struct TempDir {
  fs::path path;
  TempDir() {
    path = fs::temp_directory_path() / ("epr-scene-fetch-" + std::to_string(::getpid()) + "-" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(path);
    fs::create_directories(path);
  }
  ~TempDir() { fs::remove_all(path); }
  std::string str() const { return path.string(); }
};

// The stream a master sends for `b`: manifest, then each file's bytes in `chunk` sized pieces.
std::vector<v1::SceneChunk> scene_stream(const SceneBundleData& b, size_t chunk) {
  std::vector<v1::SceneChunk> out;
  v1::SceneChunk m;
  auto* man = m.mutable_manifest();
  man->set_content_hash(content_hash(b));
  man->set_entry_path(b.entry_path);
  uint64_t total = 0;
  for (const auto& [path, data] : b.files) {
    auto* f = man->add_files();
    f->set_path(path);
    f->set_size_bytes(data.size());
    total += data.size();
  }
  man->set_total_bytes(total);
  out.push_back(m);
  for (size_t i = 0; i < b.files.size(); ++i) {
    const std::string& data = b.files[i].second;
    for (size_t off = 0; off < data.size(); off += chunk) {
      v1::SceneChunk c;
      c.mutable_data()->set_file_index(uint32_t(i));
      c.mutable_data()->set_offset(off);
      c.mutable_data()->set_data(data.substr(off, chunk));
      out.push_back(c);
    }
  }
  return out;
}

std::optional<std::string> receive(const std::string& root, const std::string& hash,
                                   const std::vector<v1::SceneChunk>& chunks, std::string* entry) {
  SceneReceiver rx(root, hash);
  for (const auto& c : chunks)
    if (auto err = rx.add(c)) return err;
  return rx.finish(entry);
}

bool has_temp_folders(const std::string& root) {
  std::error_code ec;
  for (fs::directory_iterator it(fs::path(root) / "scenes", ec), end; !ec && it != end; it.increment(ec))
    if (it->path().filename().string().rfind(".tmp-", 0) == 0) return true;
  return false;
}

TEST(SceneFetch, ReceivesARealSceneIntoTheCache) {
  TempDir dir;
  const SceneBundleData b = bundle_scene(kCornellObj);
  ASSERT_EQ(b.files.size(), 2u);  // OBJ + MTL
  const std::string hash = content_hash(b);
  EXPECT_FALSE(cached_scene_entry(dir.str(), hash));

  std::string entry;
  const auto err = receive(dir.str(), hash, scene_stream(b, 1000), &entry);
  ASSERT_FALSE(err) << *err;
  EXPECT_EQ(entry, (dir.path / "scenes" / hash / b.entry_path).string());
  EXPECT_EQ(cached_scene_entry(dir.str(), hash), entry);
  EXPECT_EQ(cached_scene_hashes(dir.str()), std::vector<std::string>{hash});
  EXPECT_FALSE(has_temp_folders(dir.str()));
  // The files are byte for byte the bundle's, and the scene loads like the original.
  for (const auto& [path, data] : b.files) {
    std::ifstream in(dir.path / "scenes" / hash / path, std::ios::binary);
    const std::string got((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    EXPECT_EQ(got, data) << path;
  }
  EXPECT_EQ(load_scene(entry).triangle_count(), load_scene(kCornellObj).triangle_count());
  // load_bundle reuses the copy (same layout).
  EXPECT_EQ(load_bundle(b, dir.str()).triangle_count(), load_scene(kCornellObj).triangle_count());
}

TEST(SceneFetch, EmptyFilesAndUnsortedManifests) {
  TempDir dir;
  SceneBundleData b;
  b.entry_path = "scene.obj";
  b.files = {{"z/empty.txt", ""}, {"scene.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"}, {"a.txt", ""}};
  std::string entry;
  const auto err = receive(dir.str(), content_hash(b), scene_stream(b, 5), &entry);
  ASSERT_FALSE(err) << *err;
  EXPECT_TRUE(fs::exists(dir.path / "scenes" / content_hash(b) / "z/empty.txt"));
  EXPECT_EQ(fs::file_size(entry), b.files[1].second.size());
}

TEST(SceneFetch, CopiesWithoutAnEntryFileAreCompletedByAFetch) {
  TempDir dir;
  const SceneBundleData b = bundle_scene(kCornellObj);
  const std::string hash = content_hash(b);
  load_bundle(b, dir.str());  // writes the folder without .entry
  EXPECT_EQ(cached_scene_hashes(dir.str()), std::vector<std::string>{hash});
  EXPECT_FALSE(cached_scene_entry(dir.str(), hash));
  std::string entry;
  ASSERT_FALSE(receive(dir.str(), hash, scene_stream(b, 4096), &entry));
  EXPECT_EQ(cached_scene_entry(dir.str(), hash), entry);
  EXPECT_FALSE(has_temp_folders(dir.str()));
}

TEST(SceneFetch, ConcurrentFetchesOfOneSceneDoNotCollide) {
  TempDir dir;
  const SceneBundleData b = bundle_scene(kCornellObj);
  const auto chunks = scene_stream(b, 512);
  std::vector<std::thread> threads;
  std::vector<std::optional<std::string>> errors(4);
  std::vector<std::string> entries(4);
  for (int i = 0; i < 4; ++i)
    threads.emplace_back(
        [&, i] { errors[size_t(i)] = receive(dir.str(), content_hash(b), chunks, &entries[size_t(i)]); });
  for (auto& t : threads) t.join();
  for (int i = 0; i < 4; ++i) {
    EXPECT_FALSE(errors[size_t(i)]) << *errors[size_t(i)];
    EXPECT_EQ(entries[size_t(i)], entries[0]);
  }
  EXPECT_FALSE(has_temp_folders(dir.str()));
  EXPECT_TRUE(cached_scene_entry(dir.str(), content_hash(b)));
}

TEST(SceneFetch, MalformedStreamsAreRefusedAndLeaveNothingBehind) {
  const SceneBundleData b = bundle_scene(kCornellObj);
  const std::string hash = content_hash(b);
  using Chunks = std::vector<v1::SceneChunk>;
  const std::vector<std::pair<const char*, std::function<void(Chunks&)>>> cases = {
      {"data before the manifest", [](Chunks& c) { std::swap(c[0], c[1]); }},
      {"two manifests", [](Chunks& c) { c.insert(c.begin() + 1, c[0]); }},
      {"other scene's hash", [](Chunks& c) { c[0].mutable_manifest()->set_content_hash(std::string(64, 'a')); }},
      {"unsafe path", [](Chunks& c) { c[0].mutable_manifest()->mutable_files(0)->set_path("../evil.mtl"); }},
      {"absolute path", [](Chunks& c) { c[0].mutable_manifest()->mutable_files(0)->set_path("/etc/evil"); }},
      {"reserved name", [](Chunks& c) { c[0].mutable_manifest()->mutable_files(0)->set_path(".complete"); }},
      {"duplicate path",
       [](Chunks& c) {
         auto* m = c[0].mutable_manifest();
         m->mutable_files(1)->set_path(m->files(0).path());
       }},
      {"entry not a file", [](Chunks& c) { c[0].mutable_manifest()->set_entry_path("other.obj"); }},
      {"total mismatch", [](Chunks& c) { c[0].mutable_manifest()->set_total_bytes(1); }},
      {"gap", [](Chunks& c) { c.erase(c.begin() + 2); }},
      {"offset wrong", [](Chunks& c) { c[2].mutable_data()->set_offset(c[2].data().offset() + 1); }},
      {"file index out of range", [](Chunks& c) { c[1].mutable_data()->set_file_index(7); }},
      {"back to an earlier file", [](Chunks& c) { c.push_back(c[1]); }},
      {"more bytes than the file", [](Chunks& c) { c.back().mutable_data()->mutable_data()->append("xx"); }},
      {"truncated", [](Chunks& c) { c.pop_back(); }},
      {"corrupted byte", [](Chunks& c) { (*c[1].mutable_data()->mutable_data())[10] ^= 1; }},
      {"empty chunk", [](Chunks& c) { c.insert(c.begin() + 1, v1::SceneChunk()); }},
  };
  for (const auto& [name, mutate] : cases) {
    TempDir dir;
    Chunks chunks = scene_stream(b, 700);
    ASSERT_GT(chunks.size(), 4u);
    mutate(chunks);
    std::string entry;
    EXPECT_TRUE(receive(dir.str(), hash, chunks, &entry).has_value()) << name;
    EXPECT_FALSE(cached_scene_entry(dir.str(), hash)) << name;
    EXPECT_FALSE(has_temp_folders(dir.str())) << name;
    EXPECT_FALSE(fs::exists(dir.path / "evil.mtl")) << name;
  }
  SceneFetchLimits small;
  small.max_total_bytes = 100;
  TempDir dir;
  SceneReceiver rx(dir.str(), hash, small);
  EXPECT_TRUE(rx.add(scene_stream(b, 700)[0]).has_value());
  EXPECT_THROW(SceneReceiver(dir.str(), "not-a-hash"), std::invalid_argument);
}

// A write the disk refuses (here: over RLIMIT_FSIZE, EFBIG, as a full disk gives ENOSPC) is the
// worker's disk, named with the system's reason, not blamed on the scene.
TEST(SceneFetch, AWriteTheDiskRefusesIsTheWorkersDiskWithTheSystemsReason) {
  TempDir dir;
  SceneBundleData b;
  b.entry_path = "big.obj";
  b.files = {{b.entry_path, "# big\n" + std::string(256 << 10, 'x')}};
  const auto chunks = scene_stream(b, 64 << 10);
  SceneReceiver rx(dir.str(), content_hash(b));
  rlimit old{};
  ASSERT_EQ(::getrlimit(RLIMIT_FSIZE, &old), 0);
  const auto old_handler = std::signal(SIGXFSZ, SIG_IGN);  // the write fails with EFBIG instead
  rlimit small = old;
  small.rlim_cur = 100 << 10;
  ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &small), 0);
  std::optional<std::string> err;
  for (const auto& c : chunks)
    if ((err = rx.add(c))) break;
  ::setrlimit(RLIMIT_FSIZE, &old);
  std::signal(SIGXFSZ, old_handler);
  ASSERT_TRUE(err);
  EXPECT_TRUE(rx.disk_failure());
  EXPECT_NE(err->find(std::strerror(EFBIG)), std::string::npos) << *err;
  EXPECT_NE(err->find("the worker's scene cache " + dir.str()), std::string::npos) << *err;
  EXPECT_NE(err->find("'big.obj'"), std::string::npos) << *err;
}

// A cache whose scenes folder is gone for a regular file: a disk failure too, and CacheRoot's
// private fallback folder takes the scene (removed with the CacheRoot).
TEST(SceneFetch, ACacheThatCannotTakeASceneHasAPrivateFallback) {
  TempDir dir;
  std::string fallback;
  {
    CacheRoot root(dir.str());
    ASSERT_EQ(root.path(), dir.str());
    EXPECT_EQ(root.fallback_if_made(), "");
    fs::remove_all(dir.path / "scenes");
    std::ofstream(dir.path / "scenes") << "x\n";
    const SceneBundleData b = bundle_scene(kCornellObj);
    std::string entry;
    SceneReceiver rx(root.path(), content_hash(b));
    const auto err = rx.add(scene_stream(b, 1 << 20)[0]);
    ASSERT_TRUE(err);
    EXPECT_TRUE(rx.disk_failure());
    EXPECT_NE(err->find(std::strerror(ENOTDIR)), std::string::npos) << *err;
    fallback = root.fallback();
    EXPECT_NE(fallback, dir.str());
    EXPECT_EQ(root.fallback(), fallback);  // made once
    EXPECT_EQ(receive(fallback, content_hash(b), scene_stream(b, 1 << 20), &entry), std::nullopt);
    EXPECT_TRUE(fs::exists(entry));
    EXPECT_EQ(cached_scene_entry(fallback, content_hash(b)), entry);
  }
  EXPECT_FALSE(fs::exists(fallback));
}

}  // namespace
}  // namespace epr
