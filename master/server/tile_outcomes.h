// What the master makes of a tile result: expect()'s verdict on a SubmitTile header, commit()'s
// outcome, and the results it drops, counted by reason.
#pragma once

#include <cstdint>
#include <string>

#include "wire/tile_result_stream.h"

namespace epr {

/// expect()'s verdict on a SubmitTile header.
enum class TileVerdict {
  kExpected,      // read and assembled against TileCheck::expectation
  kInvalid,       // refused (INVALID_ARGUMENT), a failure of the worker holding the lease
  kStaleRound,    // the job ended or its round moved on: drained, acknowledged as stale
  kEarlierEpoch,  // leased by an earlier run of the master (its round is traced again): as stale
  kUnknownJob,    // no such job (finished and forgotten, or never existed): as stale
};

struct TileCheck {
  TileVerdict verdict = TileVerdict::kInvalid;
  TileExpectation expectation;  // with kExpected
  std::string why;              // otherwise: the reason, for the worker's ack or error

  /// Drained to its end and acknowledged as stale (rather than refused or read).
  bool stale() const {
    return verdict == TileVerdict::kStaleRound || verdict == TileVerdict::kEarlierEpoch ||
           verdict == TileVerdict::kUnknownJob;
  }
};

enum class CommitOutcome { kCommitted, kDuplicate, kStale };

/// Why a complete tile result was dropped instead of committed.
enum class DropReason {
  kStaleRound,    // for a round (or a job state) that moved on, e.g. the late copy of a re-leased tile
  kDuplicate,     // for a tile already committed from another lease
  kEarlierEpoch,  // for a lease of an earlier run of the master
};

/// Dropped tile results by reason, in this master's run (JobCounters::tiles_dropped is the total
/// over every run of the job, checkpointed with it).
struct TileDrops {
  uint64_t stale_round = 0, duplicate = 0, earlier_epoch = 0;

  uint64_t& operator[](DropReason r) {
    return r == DropReason::kStaleRound ? stale_round : r == DropReason::kDuplicate ? duplicate : earlier_epoch;
  }
  uint64_t at(DropReason r) const { return const_cast<TileDrops&>(*this)[r]; }
  uint64_t total() const { return stale_round + duplicate + earlier_epoch; }
  TileDrops& operator+=(const TileDrops& o) {
    stale_round += o.stale_round;
    duplicate += o.duplicate;
    earlier_epoch += o.earlier_epoch;
    return *this;
  }
  bool operator==(const TileDrops&) const = default;
};

/// The reasons with their names in the monitoring JSON and the metrics' `reason` label.
inline constexpr struct {
  DropReason reason;
  const char* name;
} kDropReasons[] = {{DropReason::kStaleRound, "stale_round"},
                    {DropReason::kDuplicate, "duplicate"},
                    {DropReason::kEarlierEpoch, "earlier_epoch"}};

}  // namespace epr
