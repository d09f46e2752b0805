// The worker's scene cache: file scenes received with WorkerService.FetchScene, stored by content
// hash in the layout wire/scene_bundle.cpp's load_bundle uses, so either can reuse the other's copy:
//
//   CACHE_ROOT/scenes/HASH/<the scene's files>   relative paths as in the manifest
//   CACHE_ROOT/scenes/HASH/.complete             "HASH\n", written last: the folder is complete
//   CACHE_ROOT/scenes/HASH/.entry                the entry path (this file adds it; load_bundle's
//                                                copies lack it and are fetched again once to add it)
//
// SceneReceiver checks a SceneChunk stream (proto/epr/v1/scene.proto: a manifest, then every file's
// bytes in manifest order, increasing offsets, no gaps), writes the files into a private temporary
// folder as they arrive (memory stays at one chunk), verifies sizes and the content hash at the end
// and renames the folder into place, so a crash or a bad stream never leaves half a scene behind. The
// temporary folder name is unique per receiver, so several workers in one process (the embedded
// render) can fetch the same scene at once: the first rename wins, the others discard their copy.
//
// The cache is bounded by size: trim_scene_cache removes the least recently used complete scenes
// (a scene is used when a job loads it: touch_cached_scene sets its .complete marker's modification
// time). CacheRoot picks the folder: the configured one when it can be written, else a private
// temporary one (a HOME that is not writable must not stop a worker).
#pragma once

#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "epr/v1/scene.pb.h"
#include "wire/rpc/chunked.h"

namespace epr {

struct SceneFetchLimits {
  uint64_t max_total_bytes = 4ull << 30;  // sum of file sizes
  uint64_t max_files = 100000;
  uint64_t max_chunk_bytes = rpc::kChunkBytes;  // SceneFileData.data, per the proto
};

/// The entry file of a complete cached scene ("CACHE_ROOT/scenes/HASH/ENTRY"), or nullopt if the
/// scene is not cached or its entry path is unknown (copies written by load_bundle).
std::optional<std::string> cached_scene_entry(const std::string& cache_root, const std::string& content_hash);

/// Content hashes of the complete cached scenes (WorkerInfo.cached_scenes), sorted.
std::vector<std::string> cached_scene_hashes(const std::string& cache_root);

/// True for a lowercase hex SHA-256 (64 characters), the only form a cache folder name may take.
bool is_content_hash(const std::string& s);

/// Marks a cached scene as used now (the order trim_scene_cache follows). No-op if it is not cached.
void touch_cached_scene(const std::string& cache_root, const std::string& content_hash);

/// Removes complete cached scenes, least recently used first, until those left take at most
/// `max_bytes`; never `keep` (the scene a job is about to load). Returns the hashes removed.
std::vector<std::string> trim_scene_cache(const std::string& cache_root, uint64_t max_bytes,
                                          const std::string& keep = "");

/// The worker's cache folder: `wanted` when it can be created and written into; otherwise a private
/// folder TMPDIR/epr-worker-cache-PID-XXXXXX, removed when this object is destroyed. Throws
/// std::runtime_error if neither can be made.
class CacheRoot {
 public:
  explicit CacheRoot(const std::string& wanted);
  ~CacheRoot();
  CacheRoot(const CacheRoot&) = delete;
  CacheRoot& operator=(const CacheRoot&) = delete;

  const std::string& path() const { return path_; }
  /// Why `wanted` is not used; empty when it is.
  const std::string& fallback_reason() const { return fallback_reason_; }
  /// The private temporary folder scenes go to when path() fails to take one (a full disk): made on
  /// first use, removed when this object is destroyed; path() itself when that is already one.
  /// Throws std::runtime_error with the reason if it cannot be made. Thread-safe.
  std::string fallback();
  /// fallback() if it was made, else empty.
  std::string fallback_if_made() const;

 private:
  std::string path_;
  std::string fallback_reason_;
  mutable std::mutex mu_;
  std::string fallback_;  // made by fallback(); removed by the destructor
};

/// A scene could not be written into a worker's cache: the worker's disk, not the scene
/// (SceneReceiver::disk_failure); the message has the system's reason.
class CacheWriteError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

class SceneReceiver {
 public:
  /// Throws std::invalid_argument unless `expected_hash` is a content hash.
  SceneReceiver(std::string cache_root, std::string expected_hash, SceneFetchLimits limits = {});
  ~SceneReceiver();  // removes the temporary folder unless finish() moved it into place
  SceneReceiver(const SceneReceiver&) = delete;
  SceneReceiver& operator=(const SceneReceiver&) = delete;

  /// Empty if the chunk is acceptable, otherwise why not. Errors are final.
  std::optional<std::string> add(const v1::SceneChunk& chunk);
  /// After the last chunk: checks that every file is complete and the content hash matches, then
  /// moves the scene into the cache. Sets `*entry_file` to the entry file's full path.
  std::optional<std::string> finish(std::string* entry_file);

  uint64_t bytes_received() const { return bytes_received_; }
  /// The error is this worker's disk (a write, a folder, a rename in the cache failed: the message
  /// has the system's reason), not the stream or the scene.
  bool disk_failure() const { return disk_failure_; }

 private:
  std::optional<std::string> fail(std::string reason);
  std::optional<std::string> disk_fail(const std::string& what, const std::string& reason);
  std::optional<std::string> add_manifest(const v1::SceneManifest& m);
  std::optional<std::string> add_data(const v1::SceneFileData& d);
  /// Closes the current file after checking it is complete; advances to the next one.
  std::optional<std::string> close_current();

  std::string cache_root_, hash_;
  SceneFetchLimits limits_;
  std::string tmp_dir_;
  bool have_manifest_ = false, finished_ = false, disk_failure_ = false;
  std::optional<std::string> error_;
  std::string entry_path_;
  std::vector<std::pair<std::string, uint64_t>> files_;  // (path, size) in manifest order
  size_t current_ = 0;                                   // file being written
  rpc::ChunkTracker written_{0};                         // its bytes so far
  uint64_t bytes_received_ = 0;
  struct OpenFile;
  std::unique_ptr<OpenFile> out_;
};

}  // namespace epr
