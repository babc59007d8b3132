// SHA-256 (FIPS 180-4), for the table files' content hash (hexgym.mbl.table.content_sha256).
#ifndef HEXGYM_NATIVE_SHA256_H_
#define HEXGYM_NATIVE_SHA256_H_

#include <cstddef>
#include <cstdint>
#include <string>

namespace hexgym {

class Sha256 {
 public:
  Sha256();
  void Update(const void* data, size_t size);
  void Update(const std::string& text) { Update(text.data(), text.size()); }
  // The digest as 64 lowercase hex digits; the object is spent afterwards.
  std::string HexDigest();

 private:
  void Block(const unsigned char* block);
  uint32_t h_[8];
  unsigned char buffer_[64];
  size_t buffered_ = 0;
  uint64_t length_ = 0;  // bytes
};

}  // namespace hexgym

#endif  // HEXGYM_NATIVE_SHA256_H_
