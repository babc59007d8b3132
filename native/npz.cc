// Reading .npz archives: zip central directory (with zip64), inflate (zlib), .npy headers.
#include "npz.h"

#include <zlib.h>

#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iterator>

namespace hexgym {
namespace {

using Bytes = std::vector<unsigned char>;

uint64_t Le(const Bytes& b, size_t at, int n) {
  if (at + n > b.size()) throw NpzError("truncated zip record");
  uint64_t v = 0;
  for (int i = n - 1; i >= 0; --i) v = (v << 8) | b[at + i];
  return v;
}

struct Member {
  std::string name;
  uint64_t method, crc, csize, usize, offset;
};

// The central directory's entries; zip64 sizes and offsets come from the 0x0001 extra field.
std::vector<Member> CentralDirectory(const Bytes& z) {
  if (z.size() < 22) throw NpzError("not a zip archive (too short)");
  size_t eocd = std::string::npos;
  size_t lowest = z.size() > 65557 ? z.size() - 65557 : 0;
  for (size_t i = z.size() - 22 + 1; i-- > lowest;) {
    if (Le(z, i, 4) == 0x06054b50) { eocd = i; break; }
  }
  if (eocd == std::string::npos) throw NpzError("not a zip archive (no end-of-directory record)");
  uint64_t count = Le(z, eocd + 10, 2), cd_offset = Le(z, eocd + 16, 4);
  if ((count == 0xFFFF || cd_offset == 0xFFFFFFFF) && eocd >= 20 && Le(z, eocd - 20, 4) == 0x07064b50) {
    uint64_t z64 = Le(z, eocd - 20 + 8, 8);
    if (Le(z, z64, 4) != 0x06064b50) throw NpzError("corrupt zip64 end-of-directory record");
    count = Le(z, z64 + 32, 8);
    cd_offset = Le(z, z64 + 48, 8);
  }
  std::vector<Member> members;
  size_t at = cd_offset;
  for (uint64_t k = 0; k < count; ++k) {
    if (Le(z, at, 4) != 0x02014b50) throw NpzError("corrupt zip central directory");
    Member m;
    m.method = Le(z, at + 10, 2);
    m.crc = Le(z, at + 16, 4);
    m.csize = Le(z, at + 20, 4);
    m.usize = Le(z, at + 24, 4);
    size_t name_len = Le(z, at + 28, 2), extra_len = Le(z, at + 30, 2), comment_len = Le(z, at + 32, 2);
    m.offset = Le(z, at + 42, 4);
    if (at + 46 + name_len + extra_len > z.size()) throw NpzError("truncated zip central directory");
    m.name.assign(reinterpret_cast<const char*>(&z[at + 46]), name_len);
    for (size_t e = at + 46 + name_len; e + 4 <= at + 46 + name_len + extra_len;) {
      size_t id = Le(z, e, 2), len = Le(z, e + 2, 2), p = e + 4;
      if (id == 0x0001) {  // zip64: only the fields that overflowed are present, in this order
        if (m.usize == 0xFFFFFFFF) { m.usize = Le(z, p, 8); p += 8; }
        if (m.csize == 0xFFFFFFFF) { m.csize = Le(z, p, 8); p += 8; }
        if (m.offset == 0xFFFFFFFF) { m.offset = Le(z, p, 8); }
      }
      e += 4 + len;
    }
    members.push_back(m);
    at += 46 + name_len + extra_len + comment_len;
  }
  return members;
}

Bytes Extract(const Bytes& z, const Member& m) {
  if (Le(z, m.offset, 4) != 0x04034b50) throw NpzError("corrupt zip member " + m.name);
  uint64_t data = m.offset + 30 + Le(z, m.offset + 26, 2) + Le(z, m.offset + 28, 2);
  if (data + m.csize > z.size()) throw NpzError("zip member " + m.name + " is truncated");
  Bytes out(m.usize);
  if (m.method == 0) {
    if (m.csize != m.usize) throw NpzError("zip member " + m.name + ": stored sizes disagree");
    std::memcpy(out.data(), &z[data], m.usize);
  } else if (m.method == 8) {
    z_stream s{};
    if (inflateInit2(&s, -MAX_WBITS) != Z_OK) throw NpzError("zlib initialisation failed");
    s.next_in = const_cast<unsigned char*>(&z[data]);
    s.avail_in = static_cast<uInt>(m.csize);
    s.next_out = out.data();
    s.avail_out = static_cast<uInt>(m.usize);
    int rc = inflate(&s, Z_FINISH);
    inflateEnd(&s);
    if (rc != Z_STREAM_END || s.total_out != m.usize) throw NpzError("zip member " + m.name + " does not inflate");
  } else {
    throw NpzError("zip member " + m.name + " uses unsupported compression method " + std::to_string(m.method));
  }
  if (crc32(0L, out.data(), static_cast<uInt>(out.size())) != m.crc) {
    throw NpzError("zip member " + m.name + " fails its CRC check");
  }
  return out;
}

// The quoted value after `'key': ` in a .npy header dict, or the raw text up to the next
// top-level comma for unquoted values (True/False, a shape tuple).
std::string HeaderField(const std::string& header, const std::string& key) {
  size_t k = header.find("'" + key + "'");
  if (k == std::string::npos) throw NpzError("npy header lacks '" + key + "'");
  size_t v = header.find(':', k);
  if (v == std::string::npos) throw NpzError("npy header is malformed");
  ++v;
  while (v < header.size() && header[v] == ' ') ++v;
  if (header[v] == '\'') {
    size_t end = header.find('\'', v + 1);
    return header.substr(v + 1, end - v - 1);
  }
  if (header[v] == '(') return header.substr(v, header.find(')', v) - v + 1);
  return header.substr(v, header.find(',', v) - v);
}

NpyArray ParseNpy(const Bytes& b, const std::string& name) {
  if (b.size() < 10 || std::memcmp(b.data(), "\x93NUMPY", 6) != 0) throw NpzError(name + " is not a .npy array");
  int major = b[6];
  size_t header_len = major == 1 ? Le(b, 8, 2) : Le(b, 8, 4);
  size_t start = major == 1 ? 10 : 12;
  if (start + header_len > b.size()) throw NpzError(name + ": truncated .npy header");
  std::string header(reinterpret_cast<const char*>(&b[start]), header_len);
  NpyArray a;
  a.descr = HeaderField(header, "descr");
  if (HeaderField(header, "fortran_order") != "False") throw NpzError(name + " is not in C order");
  std::string shape = HeaderField(header, "shape");
  size_t count = 1;
  for (const char* p = shape.c_str() + 1; *p && *p != ')';) {
    char* end;
    long n = std::strtol(p, &end, 10);
    if (end == p) { ++p; continue; }
    a.shape.push_back(n);
    count *= static_cast<size_t>(n);
    p = end;
  }
  const unsigned char* data = &b[start + header_len];
  size_t avail = b.size() - start - header_len;
  if (a.descr == "<f8") {
    if (avail != count * 8) throw NpzError(name + ": data size does not match its shape");
    a.f8.resize(count);
    std::memcpy(a.f8.data(), data, count * 8);  // the platform is little-endian (x86-64, arm64)
  } else if (a.descr.rfind("<U", 0) == 0) {
    size_t width = std::strtoul(a.descr.c_str() + 2, nullptr, 10);
    if (avail != count * width * 4) throw NpzError(name + ": data size does not match its shape");
    for (size_t i = 0; i < count; ++i) {
      std::string s;
      for (size_t c = 0; c < width; ++c) {
        uint32_t cp = static_cast<uint32_t>(Le(b, start + header_len + (i * width + c) * 4, 4));
        if (cp == 0) break;
        if (cp > 127) throw NpzError(name + ": non-ASCII text");
        s.push_back(static_cast<char>(cp));
      }
      a.strings.push_back(s);
    }
  } else {
    throw NpzError(name + " has dtype " + a.descr + ", expected <f8");
  }
  return a;
}

}  // namespace

std::map<std::string, NpyArray> ReadNpz(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) throw NpzError("cannot be opened");
  Bytes z((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  std::map<std::string, NpyArray> arrays;
  for (const Member& m : CentralDirectory(z)) {
    std::string name = m.name.size() > 4 && m.name.substr(m.name.size() - 4) == ".npy"
                           ? m.name.substr(0, m.name.size() - 4) : m.name;
    arrays[name] = ParseNpy(Extract(z, m), m.name);
  }
  return arrays;
}

}  // namespace hexgym
