#include "wire/rpc/chunked.h"

#include <fmt/format.h>

namespace epr::rpc {

bool for_each_chunk(std::string_view bytes, const std::function<bool(uint64_t offset, std::string_view piece)>& send) {
  for (size_t offset = 0; offset < bytes.size(); offset += kChunkBytes)
    if (!send(offset, bytes.substr(offset, kChunkBytes))) return false;
  return true;
}

std::optional<std::string> ChunkTracker::add(uint64_t offset, uint64_t n) {
  if (offset != received_) return fmt::format("data at offset {}, expected {}", offset, received_);
  if (n > size_ - received_) return fmt::format("more than the {} bytes announced", size_);
  received_ += n;
  return std::nullopt;
}

bool send_scene(const SceneBundleData& bundle, const std::function<bool(const v1::SceneChunk&)>& send) {
  v1::SceneChunk chunk;
  auto* m = chunk.mutable_manifest();
  m->set_content_hash(content_hash(bundle));
  m->set_entry_path(bundle.entry_path);
  m->set_total_bytes(bundle.total_bytes());
  for (const auto& [path, data] : bundle.files) {
    auto* f = m->add_files();
    f->set_path(path);
    f->set_size_bytes(data.size());
  }
  if (!send(chunk)) return false;
  for (size_t i = 0; i < bundle.files.size(); ++i) {
    const bool sent = for_each_chunk(bundle.files[i].second, [&](uint64_t offset, std::string_view piece) {
      chunk.Clear();
      auto* d = chunk.mutable_data();
      d->set_file_index(uint32_t(i));
      d->set_offset(offset);
      d->set_data(piece.data(), piece.size());
      return send(chunk);
    });
    if (!sent) return false;
  }
  return true;
}

std::vector<v1::SceneChunk> scene_chunks(const SceneBundleData& bundle) {
  std::vector<v1::SceneChunk> out;
  send_scene(bundle, [&](const v1::SceneChunk& c) {
    out.push_back(c);
    return true;
  });
  return out;
}

}  // namespace epr::rpc
