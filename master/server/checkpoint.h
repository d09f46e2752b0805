// Checkpoints of the master's jobs in its state directory (DESIGN.md section 4): a master killed
// with SIGKILL resumes every job from the last round it closed.
//
// Layout of the state directory:
//   epoch                       this master's run counter (lease ids carry it, see JobManager)
//   lock                        locked by the master using the folder (master/server/state_dir_lock.h)
//   scenes/HASH.scene           each scene bundle once, by content hash
//   jobs/ID/spec.ckpt           the job as submitted (written once, at submit)
//   jobs/ID/progress.ckpt       state, counters and FrameState after the newest closed round
//   jobs/ID/progress.prev.ckpt  the one before: used when the newest is torn or corrupt
//   jobs/ID/*.exr, *.png, ...   results of a finished job
//
// Every file is sealed: a 32-byte header (magic "EPRSTATE", format version, record kind, payload
// length, CRC-32 of the payload, CRC-32 of the header) and the payload. A file whose length, magic,
// kind, version or checksums do not match is rejected with CheckpointError; the reader then uses the
// previous checkpoint, and a job with none restarts from round 0. Files are replaced atomically:
// written to a temp file in the same folder, fsynced, renamed over, and the folder fsynced.
// Payloads are little-endian (the host order; other hosts are refused at compile time).
#pragma once

#include <cstdint>
#include <filesystem>
#include <map>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "common/check.h"
#include "master/frame_state.h"
#include "master/server/checkpoint_error.h"
#include "master/server/job.h"
#include "wire/scene_bundle.h"

namespace epr {

enum class RecordKind : uint32_t { kEpoch = 1, kScene = 2, kJobSpec = 3, kJobProgress = 4 };

// Version 2 added tiles_speculative and worker_failures to the progress record; version 1 files
// are still read (those two counters then start at 0). Version 3 stores the accumulation of a
// progress record's frame as the back-ends' cells ({float r, g, b; uint32 n} per subpixel, written
// span by span straight from the live accumulation) instead of separate sum and count arrays: the
// frame of an older progress record is refused (the record's other fields are read; the job starts
// again from round 0, the reason logged). Version 4 adds the variance combination's per-pixel
// arrays to a frame, after the skip mask (empty for the fixed rule); a version 3 frame has none, so
// it restores into a fixed-rule job as before. Version 5 adds the glossy sums (FrameSnapshot::
// glossy_sum) after those, and its vertex records of microfacet materials carry their diffuse share
// only (DESIGN.md "Diffuse-share reprojection"): an older frame's accumulation holds whole radiance
// and its path sums no glossy parts, so frames older than version 5 are refused as version 3 refused
// older layouts (the job starts again from round 0, the reason logged). Version 6 adds the variance
// combination's per-half path sums (FrameSnapshot::path_half_sum) after the glossy sums and holds its B
// per half (2 per pixel): a version 5 frame of the variance combination does not restore (FrameState::
// restore names why; the job starts again from round 0), a fixed-rule one does. Other records did not change.
inline constexpr uint32_t kCheckpointVersion = 6;
inline constexpr uint32_t kOldestCheckpointVersion = 1;
inline constexpr uint32_t kOldestFrameVersion = 5;
inline constexpr size_t kSealHeaderBytes = 32;

/// Header + payload (see the file comment).
std::string seal(RecordKind kind, std::string_view payload);
/// The payload of a sealed file's bytes (and its format version in *version, if given);
/// CheckpointError saying what is wrong otherwise.
std::string unseal(RecordKind kind, std::string_view bytes, uint32_t* version = nullptr);

/// Replaces `path` with `bytes` atomically and durably (temp file, fsync, rename, fsync of the
/// folder). Throws std::system_error naming the file.
void write_file_atomically(const std::filesystem::path& path, std::string_view bytes);
/// The sealed payload of `path`; CheckpointError if it is missing or not valid.
std::string read_sealed(const std::filesystem::path& path, RecordKind kind, uint32_t* version = nullptr);

/// The job as submitted: everything needed to run it again from round 0.
struct JobSpecRecord {
  std::string id;
  uint64_t seq = 0;  // submission order
  int64_t submitted_ms = 0;
  std::string scene_hash;
  RenderOptions options;  // as the master runs them (the wire's JobSpec fields)
  CameraSpec camera;
  std::string name;
  int priority = 0;
  std::optional<double> time_budget_seconds;
  std::string request_id;
  BatchMembership batch;
};

/// A job's state after its newest closed round (or its end).
struct JobProgressRecord {
  JobState state = JobState::kRunning;
  std::string error;
  uint64_t triangles = 0;
  FrameProgress progress;
  ReprojectionCounts counts;
  JobCounters counters;
  int64_t started_ms = 0, finished_ms = 0;
  bool budget_exhausted = false;
  std::optional<FrameSnapshot> frame;                          // running jobs: what the next round starts from
  std::map<std::string, std::vector<unsigned char>> previews;  // finished jobs: layer -> PNG
};

std::string encode(const JobSpecRecord& r);
JobSpecRecord decode_job_spec(std::string_view payload);  // CheckpointError if malformed
std::string encode(const JobProgressRecord& r);
JobProgressRecord decode_job_progress(std::string_view payload,
                                      uint32_t version = kCheckpointVersion);  // CheckpointError if malformed

/// The spec record of a job as submitted.
JobSpecRecord spec_record(const Job& job);
/// A job's progress record as of now (a finished job's with its preview PNGs; no frame).
JobProgressRecord progress_record(const Job& job) EPR_REQUIRES(job_fields);

/// The state directory: the layout above, the keep-two rotation of progress checkpoints and the
/// fallback to the previous one. Thread-safe: the writes and load_jobs() run one at a time.
class CheckpointStore {
 public:
  /// Creates the folders if needed; throws std::filesystem::filesystem_error if it cannot.
  explicit CheckpointStore(std::filesystem::path dir);

  const std::filesystem::path& dir() const { return dir_; }
  std::filesystem::path job_dir(const std::string& id) const { return dir_ / "jobs" / id; }

  /// Reads the run counter (0 if there is none or it is unreadable), stores it plus one and returns that.
  uint64_t next_epoch() EPR_EXCLUDES(mu_);

  /// Stores a scene bundle under its hash unless a valid copy is there already.
  void save_scene(const std::string& hash, const SceneBundleData& bundle) EPR_EXCLUDES(mu_);
  /// The stored bundle; CheckpointError if missing, corrupt or not matching the hash.
  SceneBundleData load_scene(const std::string& hash) const;

  void save_spec(const JobSpecRecord& spec) EPR_EXCLUDES(mu_);
  /// Makes `record` the newest progress checkpoint; the newest so far becomes the previous one.
  void save_progress(const std::string& id, const JobProgressRecord& record) EPR_EXCLUDES(mu_);
  /// save_progress() in two steps, for a round checkpoint of a running job written without copying
  /// its frame. write_progress_file() streams the record into a temp file of its own in the job's
  /// folder, in chunks of a few MiB (no whole-file buffer), its frame taken from `frame` when given
  /// (the live FrameState's view: call it where nothing changes the frame meanwhile) -- no fsync;
  /// it returns the temp file. commit_progress() fsyncs it and makes it the newest checkpoint (on
  /// any thread). A temp file not committed is removed by the caller (or by load_jobs()).
  std::filesystem::path write_progress_file(const std::string& id, const JobProgressRecord& record,
                                            const FrameView* frame = nullptr) const;
  void commit_progress(const std::string& id, const std::filesystem::path& written) EPR_EXCLUDES(mu_);
  /// A progress file read in bounded memory: its checksum checked in one pass, its frame's per-pixel
  /// arrays read, its accumulation left in the file: FrameSnapshot::cells reads it (from the file
  /// kept open) when the frame is restored. A frame of an older format is dropped with a note in
  /// *problems. CheckpointError if the file is not valid.
  static JobProgressRecord read_progress(const std::filesystem::path& path, std::vector<std::string>* problems);
  /// Removes a forgotten job's folder.
  void remove_job(const std::string& id) EPR_EXCLUDES(mu_);

  struct LoadedJob {
    JobSpecRecord spec;
    std::optional<JobProgressRecord> progress;  // none: the job starts from round 0
    std::vector<std::string> problems;          // checkpoints that were rejected, and why
  };
  /// Every job with a readable spec, in submission order; `problems` lists the folders skipped.
  std::vector<LoadedJob> load_jobs(std::vector<std::string>* problems) const EPR_EXCLUDES(mu_);
  /// A job's newest valid progress checkpoint (falling back to the previous one).
  std::optional<JobProgressRecord> load_progress(const std::string& id, std::vector<std::string>* problems) const;
  /// A job's valid progress checkpoint after `round` rounds (the newest or the previous one), if it has one.
  std::optional<JobProgressRecord> load_progress_after(const std::string& id, int round) const;

 private:
  const std::filesystem::path dir_;
  // Guards no field: it serialises the changes to the files under dir_ (and load_jobs' walk over
  // them), so two writers never rotate the same job's progress checkpoints at once.
  mutable Mutex mu_;
};

}  // namespace epr
