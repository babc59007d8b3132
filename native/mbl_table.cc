// MBL table file checks and lookup.
#include "mbl_table.h"

#include <algorithm>
#include <cmath>
#include <map>

#include "json.h"
#include "npz.h"
#include "sha256.h"

namespace hexgym {
namespace {

constexpr double kUniformRtol = 1e-9;  // hexgym.mbl.table._UNIFORM_RTOL
constexpr int kMaxDims = 8;            // the lookup's corner buffer holds 2^8 values

std::string Join(const std::vector<std::string>& names) {
  std::string s = "[";
  for (size_t i = 0; i < names.size(); ++i) s += (i ? ", " : "") + names[i];
  return s + "]";
}

// Python's repr of a shape tuple: "(3,)", "(23, 23, 4)".
std::string TupleText(const std::vector<long>& dims) {
  std::string out = "(";
  for (size_t j = 0; j < dims.size(); ++j) out += (j ? ", " : "") + std::to_string(dims[j]);
  return out + (dims.size() == 1 ? ",)" : ")");
}

// The metadata keys the content hash covers (hexgym.mbl.table.HASHED_META_KEYS).
const char* const kHashedMetaKeys[] = {"data_hash", "format_version", "inputs", "metrics",
                                       "name",      "output",         "params", "shape"};

// hexgym.mbl.table.content_sha256: sha256 of the metadata's canonical JSON, then for each array
// "<name>|<f8|<shape tuple>" and its bytes (values, confidence, axis_0 ...).
std::string ContentHash(const Json& meta, const std::vector<std::pair<std::string, const NpyArray*>>& arrays) {
  Json hashed;
  hashed.type = Json::kObject;
  for (const char* key : kHashedMetaKeys) hashed.members.emplace_back(key, *meta.Member(key));
  Sha256 sha;
  sha.Update(hashed.Canonical());
  for (const auto& [name, a] : arrays) {
    sha.Update(name + "|<f8|" + TupleText(a->shape));
    sha.Update(a->f8.data(), a->f8.size() * sizeof(double));  // little-endian, as '<f8' is
  }
  return sha.HexDigest();
}

// The LWR parameters the values were computed with, checked as hexgym.mbl.lwr_params.LWRParams does
// (the plugin does not use them, but a file both loaders accept must be a valid table).
void CheckParams(const std::string& where, const Json& params, int d) {
  auto invalid = [&](const std::string& what) { throw TableError(where + " holds an invalid table: params " + what); };
  if (params.type != Json::kObject) invalid("is not an object");
  for (const auto& [key, value] : params.members) {
    if (key != "bandwidth" && key != "input_scales" && key != "ridge" && key != "max_neighbours" && key != "cutoff") {
      invalid("has an unknown key '" + key + "'");
    }
  }
  auto number = [&](const char* key, bool required, double fallback) {
    const Json* v = params.Member(key);
    if (!v) {
      if (required) invalid(std::string("lacks '") + key + "'");
      return fallback;
    }
    if (v->type != Json::kNumber || !std::isfinite(v->number)) invalid(std::string("'") + key + "' is not a finite number");
    return v->number;
  };
  if (!(number("bandwidth", true, 0.0) > 0)) invalid("'bandwidth' must be > 0");
  if (!(number("ridge", false, 1e-6) >= 0)) invalid("'ridge' must be >= 0");
  if (!(number("cutoff", false, 4.0) > 0)) invalid("'cutoff' must be > 0");
  const Json* k = params.Member("max_neighbours");
  if (k && k->type != Json::kNull && (k->type != Json::kNumber || !(k->number >= 1))) {
    invalid("'max_neighbours' must be >= 1 or null");
  }
  const Json* scales = params.Member("input_scales");
  if (!scales || scales->type != Json::kArray || static_cast<int>(scales->items.size()) != d) {
    invalid("'input_scales' must be " + std::to_string(d) + " numbers, one per input");
  }
  for (const Json& s : scales->items) {
    if (s.type != Json::kNumber || !std::isfinite(s.number) || !(s.number > 0)) {
      invalid("'input_scales' must be positive and finite");
    }
  }
}

}  // namespace

MblTable::MblTable(const std::string& path, const std::string& name, const std::vector<std::string>& inputs,
                   const std::string& output) {
  const std::string where = "MBL table file " + path;
  std::map<std::string, NpyArray> arrays;
  try {
    arrays = ReadNpz(path);
  } catch (const std::exception& e) {  // NpzError, or sizes in a damaged header that cannot be allocated
    throw TableError(where + " is corrupt or not a table file: " + e.what());
  }
  auto array = [&](const std::string& key) -> const NpyArray& {
    auto it = arrays.find(key);
    if (it == arrays.end()) throw TableError(where + ": array '" + key + "' is missing");
    return it->second;
  };
  const NpyArray& meta_array = array("meta");
  if (meta_array.strings.size() != 1) throw TableError(where + ": 'meta' is not one JSON string");
  Json meta;
  try {
    meta = ParseJson(meta_array.strings[0]);
  } catch (const JsonError& e) {
    throw TableError(where + ": metadata is not valid JSON: " + e.what());
  }
  const Json* version = meta.Member("format_version");
  if (!version || version->type != Json::kNumber || version->number != kTableFormatVersion) {
    throw TableError(where + " has format version " + (version ? version->Text() : std::string("(none)")) +
                     "; this plugin reads version " + std::to_string(kTableFormatVersion) + " (rebuild the table)");
  }
  const Json* file_name = meta.Member("name");
  if (!file_name || file_name->type != Json::kString || file_name->text != name) {
    throw TableError(where + " holds table " + (file_name ? file_name->Text() : std::string("(none)")) +
                     ", expected '" + name + "'");
  }
  const Json* file_inputs = meta.Member("inputs");
  std::vector<std::string> got;
  if (file_inputs && file_inputs->type == Json::kArray) {
    for (const Json& s : file_inputs->items) got.push_back(s.type == Json::kString ? s.text : s.Text());
  }
  if (got != inputs) {
    throw TableError(where + " has inputs " + Join(got) + "; the plugin expects " + Join(inputs));
  }
  const Json* file_output = meta.Member("output");
  if (!file_output || file_output->type != Json::kString || file_output->text != output) {
    throw TableError(where + " has output " + (file_output ? file_output->Text() : std::string("(none)")) +
                     "; the plugin expects '" + output + "'");
  }
  d_ = static_cast<int>(inputs.size());
  if (d_ < 1 || d_ > kMaxDims) throw TableError(where + ": tables of 1 to 8 inputs are supported");
  for (const char* key : kHashedMetaKeys) {
    if (!meta.Member(key)) throw TableError(where + ": metadata lacks '" + key + "'");
  }
  const Json* content_hash = meta.Member("content_sha256");
  if (!content_hash || content_hash->type != Json::kString) throw TableError(where + ": metadata lacks 'content_sha256'");
  const NpyArray& values = array("values");
  std::vector<long> shape;
  for (int j = 0; j < d_; ++j) {
    const NpyArray& axis = array("axis_" + std::to_string(j));
    if (axis.shape.size() != 1) throw TableError(where + ": array 'axis_" + std::to_string(j) + "' is not 1-D");
    shape.push_back(static_cast<long>(axis.f8.size()));
  }
  if (values.shape != shape || values.descr != "<f8") {
    auto text = [](const std::vector<long>& dims) {
      std::string out = "(";
      for (size_t j = 0; j < dims.size(); ++j) out += (j ? ", " : "") + std::to_string(dims[j]);
      return out + ")";
    };
    throw TableError(where + ": 'values' has shape " + text(values.shape) + " dtype " + values.descr +
                     "; its axes need shape " + text(shape) + " dtype <f8");
  }
  const Json* meta_shape = meta.Member("shape");
  std::vector<long> declared;
  if (meta_shape->type == Json::kArray) {
    for (const Json& n : meta_shape->items) {  // whole numbers, as Python's check: 23, not 23.0
      bool whole = n.type == Json::kNumber && n.raw.find_first_of(".eEnNiI") == std::string::npos;
      declared.push_back(whole ? static_cast<long>(n.number) : -1);
    }
  }
  if (declared != shape) {
    throw TableError(where + ": array 'values' has shape " + TupleText(shape) + ", expected " + TupleText(declared));
  }
  const NpyArray& confidence = array("confidence");
  if (confidence.shape != shape) {
    throw TableError(where + ": array 'confidence' has shape " + TupleText(confidence.shape) + ", expected " +
                     TupleText(shape));
  }
  std::vector<std::pair<std::string, const NpyArray*>> hashed = {{"values", &values}, {"confidence", &confidence}};
  for (int j = 0; j < d_; ++j) hashed.emplace_back("axis_" + std::to_string(j), &array("axis_" + std::to_string(j)));
  if (ContentHash(meta, hashed) != content_hash->text) {
    throw TableError(where + ": content hash mismatch (the file was altered or is corrupt)");
  }
  for (const auto& [key, a] : hashed) {
    for (double v : a->f8) {
      if (!std::isfinite(v)) throw TableError(where + ": array '" + key + "' holds non-finite numbers");
    }
  }
  CheckParams(where, *meta.Member("params"), d_);
  values_ = values.f8;
  long stride = 1;
  axes_.resize(d_);
  for (int j = d_ - 1; j >= 0; --j) {
    const std::vector<double>& a = array("axis_" + std::to_string(j)).f8;
    if (a.size() < 2) throw TableError(where + ": axis " + std::to_string(j) + " has fewer than 2 nodes");
    for (size_t i = 0; i < a.size(); ++i) {
      if (!std::isfinite(a[i]) || (i && !(a[i] > a[i - 1]))) {
        throw TableError(where + ": axis " + std::to_string(j) + " is not strictly increasing");
      }
    }
    Axis& ax = axes_[j];
    ax.nodes = a;
    ax.lo = a.front();
    ax.hi = a.back();
    ax.inv_step = static_cast<double>(a.size() - 1) / (a.back() - a.front());
    ax.imax = static_cast<long>(a.size()) - 2;
    ax.stride = stride;
    stride *= static_cast<long>(a.size());
    double step0 = a[1] - a[0];
    ax.uniform = true;
    for (size_t i = 1; i < a.size(); ++i) {
      if (std::fabs((a[i] - a[i - 1]) - step0) > kUniformRtol * std::fabs(step0)) ax.uniform = false;
    }
  }
  corner_offsets_.resize(size_t{1} << d_);
  for (size_t c = 0; c < corner_offsets_.size(); ++c) {
    long offset = 0;
    for (int j = 0; j < d_; ++j) {
      if ((c >> (d_ - 1 - j)) & 1) offset += axes_[j].stride;
    }
    corner_offsets_[c] = offset;
  }
}

double MblTable::operator()(const double* x) const {
  long base = 0;
  double frac[kMaxDims];
  for (int j = 0; j < d_; ++j) {
    const Axis& ax = axes_[j];
    double v = x[j];
    v = v < ax.lo ? ax.lo : v > ax.hi ? ax.hi : v;
    long i;
    double t;
    if (ax.uniform) {
      double pos = (v - ax.lo) * ax.inv_step;
      i = static_cast<long>(pos);
      i = i > ax.imax ? ax.imax : i;
      t = pos - static_cast<double>(i);
    } else {
      i = static_cast<long>(std::upper_bound(ax.nodes.begin(), ax.nodes.end(), v) - ax.nodes.begin()) - 1;
      i = std::min(ax.imax, i);
      t = (v - ax.nodes[i]) / (ax.nodes[i + 1] - ax.nodes[i]);
    }
    base += i * ax.stride;
    frac[j] = t;
  }
  double vals[1 << kMaxDims];
  size_t n = corner_offsets_.size();
  for (size_t c = 0; c < n; ++c) vals[c] = values_[base + corner_offsets_[c]];
  for (int j = d_ - 1; j >= 0; --j) {  // the last axis is the lowest bit: neighbours pair up
    n /= 2;
    for (size_t k = 0; k < n; ++k) vals[k] = vals[2 * k] + frac[j] * (vals[2 * k + 1] - vals[2 * k]);
  }
  return vals[0];
}

}  // namespace hexgym
