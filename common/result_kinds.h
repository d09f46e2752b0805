// The files a render leaves: one table for the single-process render (PREFIX + suffix), the master's
// job folder (stored_as), the job service (media types) and the client that downloads them.
#pragma once

#include <span>
#include <string_view>

namespace epr {

enum class ResultKind {
  kExr,           // the combined image, linear float OpenEXR
  kPng,           // the combined image, sRGB 8-bit PNG
  kJson,          // statistics
  kPathtrace,     // path samples only (sum / M), OpenEXR
  kReprojection,  // the reprojected estimate L_rp, OpenEXR
  kCounts,        // M and M' per pixel, 2-channel OpenEXR
  kSamplesExr,    // M' per pixel, 1-channel OpenEXR
  kSamplesPng,    // heat map of M', PNG
};

struct ResultKindInfo {
  ResultKind kind;
  std::string_view name;       // as the monitoring endpoint and logs name it
  std::string_view suffix;     // appended to a user's output prefix
  std::string_view stored_as;  // the file in the master's job folder
  std::string_view media_type;
  bool needs_reprojection;  // written only when the job reprojects
};

/// Every kind, in the order a render writes them (the combined EXR first).
std::span<const ResultKindInfo> result_kinds();
const ResultKindInfo& result_kind(ResultKind kind);

}  // namespace epr
