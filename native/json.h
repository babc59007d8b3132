// A small JSON reader for the table files' metadata (objects, arrays, strings, numbers), and the
// canonical form Python's json.dumps(value, sort_keys=True) writes, which the content hash covers.
#ifndef HEXGYM_NATIVE_JSON_H_
#define HEXGYM_NATIVE_JSON_H_

#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace hexgym {

class JsonError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct Json {
  enum Type { kNull, kBool, kNumber, kString, kArray, kObject };
  Type type = kNull;
  double number = 0.0;  // kNumber, kBool (0/1)
  std::string raw;      // kNumber: the number as written (an integer stays an integer)
  std::string text;     // kString (UTF-8)
  std::vector<Json> items;
  std::vector<std::pair<std::string, Json>> members;

  // The member `key` of an object (the last, as Python keeps), or nullptr.
  const Json* Member(const std::string& key) const;
  // json.dumps(value, sort_keys=True) of Python: ", " and ": " separators, ASCII with \u escapes,
  // floats as Python's repr (shortest round trip), NaN/Infinity as Python writes them.
  std::string Canonical() const;
  // A short rendering for error messages.
  std::string Text() const;
};

Json ParseJson(const std::string& text);

}  // namespace hexgym

#endif  // HEXGYM_NATIVE_JSON_H_
