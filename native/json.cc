// Recursive-descent JSON reader (RFC 8259 subset: \uXXXX escapes are kept only if ASCII).
#include "json.h"

#include <algorithm>
#include <charconv>
#include <cstdio>
#include <cmath>
#include <cstdlib>
#include <map>
#include <sstream>

namespace hexgym {
namespace {

class Reader {
 public:
  explicit Reader(const std::string& s) : s_(s) {}

  Json Value() {
    Skip();
    if (at_ >= s_.size()) throw JsonError("unexpected end of text");
    char c = s_[at_];
    Json v;
    if (c == '{') {
      v.type = Json::kObject;
      ++at_;
      if (Peek() == '}') { ++at_; return v; }
      for (;;) {
        Skip();
        std::string key = String();
        Expect(':');
        v.members.emplace_back(key, Value());
        if (Peek() == ',') { ++at_; continue; }
        Expect('}');
        return v;
      }
    }
    if (c == '[') {
      v.type = Json::kArray;
      ++at_;
      if (Peek() == ']') { ++at_; return v; }
      for (;;) {
        v.items.push_back(Value());
        if (Peek() == ',') { ++at_; continue; }
        Expect(']');
        return v;
      }
    }
    if (c == '"') {
      v.type = Json::kString;
      v.text = String();
      return v;
    }
    for (const char* word : {"null", "true", "false"}) {
      if (s_.compare(at_, std::string(word).size(), word) == 0) {
        at_ += std::string(word).size();
        v.type = word[0] == 'n' ? Json::kNull : Json::kBool;
        v.number = word[0] == 't';
        return v;
      }
    }
    char* end;
    v.number = std::strtod(s_.c_str() + at_, &end);
    if (end == s_.c_str() + at_) throw JsonError("unexpected character at offset " + std::to_string(at_));
    v.raw.assign(s_, at_, static_cast<size_t>(end - s_.c_str()) - at_);
    at_ = static_cast<size_t>(end - s_.c_str());
    v.type = Json::kNumber;
    return v;
  }

  void End() {
    Skip();
    if (at_ != s_.size()) throw JsonError("trailing text at offset " + std::to_string(at_));
  }

 private:
  void Skip() {
    while (at_ < s_.size() && (s_[at_] == ' ' || s_[at_] == '\n' || s_[at_] == '\t' || s_[at_] == '\r')) ++at_;
  }
  char Peek() {
    Skip();
    return at_ < s_.size() ? s_[at_] : '\0';
  }
  void Expect(char c) {
    if (Peek() != c) throw JsonError(std::string("expected '") + c + "' at offset " + std::to_string(at_));
    ++at_;
  }
  std::string String() {
    Expect('"');
    std::string out;
    while (at_ < s_.size() && s_[at_] != '"') {
      char c = s_[at_++];
      if (c != '\\') { out.push_back(c); continue; }
      if (at_ >= s_.size()) break;
      char e = s_[at_++];
      switch (e) {
        case 'n': out.push_back('\n'); break;
        case 't': out.push_back('\t'); break;
        case 'r': out.push_back('\r'); break;
        case 'b': out.push_back('\b'); break;
        case 'f': out.push_back('\f'); break;
        case 'u': {
          long cp = Hex4();
          if (cp >= 0xD800 && cp < 0xDC00 && s_.compare(at_, 2, "\\u") == 0) {  // a surrogate pair
            at_ += 2;
            long low = Hex4();
            if (low >= 0xDC00 && low < 0xE000) {
              cp = 0x10000 + ((cp - 0xD800) << 10) + (low - 0xDC00);
            } else {
              AppendUtf8(out, cp);
              cp = low;
            }
          }
          AppendUtf8(out, cp);
          break;
        }
        default: out.push_back(e);
      }
    }
    if (at_ >= s_.size()) throw JsonError("unterminated string");
    ++at_;
    return out;
  }

  long Hex4() {
    if (at_ + 4 > s_.size()) throw JsonError("truncated \\u escape");
    char* end;
    std::string digits = s_.substr(at_, 4);
    long cp = std::strtol(digits.c_str(), &end, 16);
    if (end != digits.c_str() + 4) throw JsonError("bad \\u escape at offset " + std::to_string(at_));
    at_ += 4;
    return cp;
  }
  static void AppendUtf8(std::string& out, long cp) {
    if (cp < 0x80) {
      out.push_back(static_cast<char>(cp));
    } else if (cp < 0x800) {
      out.push_back(static_cast<char>(0xC0 | (cp >> 6)));
      out.push_back(static_cast<char>(0x80 | (cp & 0x3F)));
    } else if (cp < 0x10000) {
      out.push_back(static_cast<char>(0xE0 | (cp >> 12)));
      out.push_back(static_cast<char>(0x80 | ((cp >> 6) & 0x3F)));
      out.push_back(static_cast<char>(0x80 | (cp & 0x3F)));
    } else {
      out.push_back(static_cast<char>(0xF0 | (cp >> 18)));
      out.push_back(static_cast<char>(0x80 | ((cp >> 12) & 0x3F)));
      out.push_back(static_cast<char>(0x80 | ((cp >> 6) & 0x3F)));
      out.push_back(static_cast<char>(0x80 | (cp & 0x3F)));
    }
  }

  const std::string& s_;
  size_t at_ = 0;
};

// Python's repr of a float: the shortest digits that read back to it, fixed notation for decimal
// exponents -4 <= e < 16 (with ".0" when integral), else d.ddde+XX (at least two exponent digits).
std::string PythonFloat(double x) {
  if (std::isnan(x)) return "NaN";
  if (std::isinf(x)) return x > 0 ? "Infinity" : "-Infinity";
  char buf[64];
  auto res = std::to_chars(buf, buf + sizeof(buf), x, std::chars_format::scientific);
  std::string sci(buf, res.ptr);  // [-]d[.ddd]e[+-]XX
  std::string sign = sci[0] == '-' ? "-" : "";
  if (!sign.empty()) sci.erase(0, 1);
  size_t e = sci.find('e');
  std::string digits = sci.substr(0, e);
  digits.erase(std::remove(digits.begin(), digits.end(), '.'), digits.end());
  int exponent = std::atoi(sci.c_str() + e + 1);
  int decpt = exponent + 1;  // digits d1 d2 ... mean 0.d1d2... x 10^decpt
  std::string out;
  if (-4 < decpt && decpt <= 16) {
    if (decpt <= 0) {
      out = "0." + std::string(-decpt, '0') + digits;
    } else if (static_cast<size_t>(decpt) >= digits.size()) {
      out = digits + std::string(decpt - digits.size(), '0') + ".0";
    } else {
      out = digits.substr(0, decpt) + "." + digits.substr(decpt);
    }
  } else {
    out = digits.substr(0, 1);
    if (digits.size() > 1) out += "." + digits.substr(1);
    char tail[16];
    std::snprintf(tail, sizeof(tail), "e%c%02d", exponent < 0 ? '-' : '+', std::abs(exponent));
    out += tail;
  }
  return sign + out;
}

// Python's json string encoding with ensure_ascii: the two-character escapes, \u00XX for other
// control characters and DEL, \uXXXX (surrogate pairs above U+FFFF) for everything beyond ASCII.
std::string PythonString(const std::string& s) {
  std::string out = "\"";
  auto u = [&out](unsigned long cp) {
    char b[8];
    std::snprintf(b, sizeof(b), "\\u%04lx", cp);
    out += b;
  };
  for (size_t i = 0; i < s.size();) {
    unsigned char c = static_cast<unsigned char>(s[i]);
    unsigned long cp = c;
    size_t n = 1;
    if (c >= 0xF0 && i + 3 < s.size()) {
      cp = ((c & 0x07UL) << 18) | ((s[i + 1] & 0x3FUL) << 12) | ((s[i + 2] & 0x3FUL) << 6) | (s[i + 3] & 0x3FUL);
      n = 4;
    } else if (c >= 0xE0 && i + 2 < s.size()) {
      cp = ((c & 0x0FUL) << 12) | ((s[i + 1] & 0x3FUL) << 6) | (s[i + 2] & 0x3FUL);
      n = 3;
    } else if (c >= 0xC0 && i + 1 < s.size()) {
      cp = ((c & 0x1FUL) << 6) | (s[i + 1] & 0x3FUL);
      n = 2;
    }
    i += n;
    switch (cp) {
      case '"': out += "\\\""; continue;
      case '\\': out += "\\\\"; continue;
      case '\n': out += "\\n"; continue;
      case '\r': out += "\\r"; continue;
      case '\t': out += "\\t"; continue;
      case '\b': out += "\\b"; continue;
      case '\f': out += "\\f"; continue;
      default: break;
    }
    if (cp >= 0x20 && cp < 0x7F) {
      out.push_back(static_cast<char>(cp));
    } else if (cp < 0x10000) {
      u(cp);
    } else {
      cp -= 0x10000;
      u(0xD800 | (cp >> 10));
      u(0xDC00 | (cp & 0x3FF));
    }
  }
  return out + "\"";
}

}  // namespace

std::string Json::Canonical() const {
  switch (type) {
    case kNull: return "null";
    case kBool: return number ? "true" : "false";
    case kNumber: {
      bool integer = raw.find_first_of(".eEnNiI") == std::string::npos;
      if (!integer) return PythonFloat(number);
      return raw == "-0" ? "0" : raw;
    }
    case kString: return PythonString(text);
    case kArray: {
      std::string out = "[";
      for (size_t i = 0; i < items.size(); ++i) out += (i ? ", " : "") + items[i].Canonical();
      return out + "]";
    }
    case kObject: {
      std::map<std::string, const Json*> sorted;  // later duplicates win, as in Python
      for (const auto& [k, v] : members) sorted[k] = &v;
      std::string out = "{";
      bool first = true;
      for (const auto& [k, v] : sorted) {
        out += (first ? "" : ", ") + PythonString(k) + ": " + v->Canonical();
        first = false;
      }
      return out + "}";
    }
  }
  return "";
}

const Json* Json::Member(const std::string& key) const {
  const Json* found = nullptr;
  for (const auto& [k, v] : members) {
    if (k == key) found = &v;
  }
  return found;
}

std::string Json::Text() const {
  switch (type) {
    case kNull: return "null";
    case kBool: return number ? "true" : "false";
    case kNumber: {
      std::ostringstream o;
      o << number;
      return o.str();
    }
    case kString: return "'" + text + "'";
    case kArray: return "[...]";
    case kObject: return "{...}";
  }
  return "";
}

Json ParseJson(const std::string& text) {
  Reader r(text);
  Json v = r.Value();
  r.End();
  return v;
}

}  // namespace hexgym
