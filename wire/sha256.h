// Incremental SHA-256 (OpenSSL's EVP), hex-encoded: scene content hashes, result checksums, and the
// checks of files received in chunks without holding them in memory.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>

struct evp_md_ctx_st;

namespace epr {

class Sha256 {
 public:
  Sha256();
  ~Sha256();
  Sha256(const Sha256&) = delete;
  Sha256& operator=(const Sha256&) = delete;

  void update(const void* data, size_t n);
  void update(const std::string& bytes) { update(bytes.data(), bytes.size()); }
  /// Eight bytes, little-endian (lengths framed into a hash).
  void update_u64le(uint64_t v);
  /// The digest as 64 lower-case hex digits; call once.
  std::string hex();

 private:
  evp_md_ctx_st* ctx_;
};

/// SHA-256 of `bytes` as 64 lower-case hex digits.
std::string sha256_hex(const std::string& bytes);

}  // namespace epr
