// Recursive-descent JSON reader (RFC 8259 subset: \uXXXX escapes are kept only if ASCII).
#include "json.h"

#include <cstdlib>
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
          long cp = std::strtol(s_.substr(at_, 4).c_str(), nullptr, 16);
          out.push_back(cp < 128 ? static_cast<char>(cp) : '?');
          at_ += 4;
          break;
        }
        default: out.push_back(e);
      }
    }
    if (at_ >= s_.size()) throw JsonError("unterminated string");
    ++at_;
    return out;
  }

  const std::string& s_;
  size_t at_ = 0;
};

}  // namespace

const Json* Json::Member(const std::string& key) const {
  for (const auto& [k, v] : members) {
    if (k == key) return &v;
  }
  return nullptr;
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
