// The render flags shared by `epr render` (embedded) and `epr submit` (cluster), so that both take
// the same job description (DESIGN.md section 2).
#pragma once

#include <CLI/CLI.hpp>
#include <filesystem>
#include <map>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "common/render_options.h"

namespace epr {

/// Which command the flags are for: kRemote leaves out what only a local render can use (--threads).
enum class RenderFlagSet { kLocal, kRemote };

/// Adds the positional SCENE and every render flag to `cmd`, writing into `o`. Flags that need more
/// than a plain conversion land in `extra` as text; finish_options turns them into options.
void add_render_flags(CLI::App* cmd, RenderOptions& o, std::map<std::string, std::string>& extra,
                      RenderFlagSet set = RenderFlagSet::kLocal);

/// Why `prefix` cannot be an output prefix (PREFIX.exr, PREFIX.png, ... are written): it is empty,
/// ends in '/', ends in "." or "..", or names a folder, so the files would be hidden or land
/// elsewhere. nullopt when it is usable.
std::optional<std::string> output_prefix_error(const std::string& prefix);

/// An output prefix that cannot be used (output_replaces_input): a usage error, nothing was written.
class OutputError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

/// Why the outputs of `prefix` (PREFIX.exr, PREFIX.json, ... and a batch's PREFIX.0001.exr, ...)
/// would replace one of `inputs`, the files a scene reads (SceneBundleData::sources, LoadReport), or
/// a scene JSON (PREFIX.json holding "obj" or "builtin"); nullopt when they would not. Files are
/// compared by identity (the same folder and name), not by how they are written.
std::optional<std::string> output_replaces_input(const std::string& prefix,
                                                 const std::vector<std::filesystem::path>& inputs);

/// The output prefix for what a user typed: "frame.exr" or "frame.png" (any case) means the prefix
/// "frame", so that the image is frame.exr and not frame.exr.exr; anything else is the prefix itself.
std::string output_prefix(const std::string& out);

/// Applies the `extra` flags (camera overrides, Russian roulette) to `o`.
/// Throws CLI::ValidationError naming the flag for malformed values.
void finish_options(RenderOptions& o, const std::map<std::string, std::string>& extra);

}  // namespace epr
