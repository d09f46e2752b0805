// A running job's preview copy: a copy of its images and statistics, and the PNGs encoded from it on
// demand by whoever asks (never on the reprojection thread). The copy exists only while someone asks
// for previews or partial results: the first ask has the reprojection thread take one between batches;
// while asks keep coming (MasterOptions::preview_interest_ms) it is renewed as rounds close, at most
// once a second; then it is dropped. A running job's partial results are encoded from it too. A
// cancelled or failed job's copy, or else its frame as it stands, is written to its folder as its
// (partial) results. A finished job's previews come from its result files; a cancelled or failed one
// keeps its last PNGs. Under the JobManager's mutex, like the rest of a Job.
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "master/frame_state.h"

namespace epr {

struct PreviewState {
  /// Where the copy stands.
  enum class Copy {
    kIdle,       // nothing under way: `images` is the copy, if there is one
    kRequested,  // asked for while there was none: the reprojection thread takes one between batches
    kTaking,     // being taken (the old one is dropped first, to bound memory), or the final results made
  };
  Copy copy = Copy::kIdle;
  std::shared_ptr<const FrameImages> images;
  std::shared_ptr<const nlohmann::json> stats;             // the statistics file as of the copy
  int round = 0;                                           // the closed round the copy reflects
  bool reprojects = false;                                 // the copy has the reprojection layers
  std::map<std::string, std::vector<unsigned char>> pngs;  // layer -> PNG
  int64_t last_ms = 0;           // the last copy, pushed later by what it cost (at most ~10 % of the thread)
  int64_t asked_ms = -1;         // when a preview or partial result was last asked for (-1: never)
  bool partial_pending = false;  // ended without a copy: drop_job stores partial results from the frame
};

}  // namespace epr
