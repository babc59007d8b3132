// An MBL table read from the .npz file hexgym.mbl.table.MBLTable.save writes, and its lookup:
// multilinear interpolation on the grid with inputs clamped to it, the same arithmetic in the
// same order as MBLTable._lookup_one (so Python and native give the same numbers).
#ifndef HEXGYM_NATIVE_MBL_TABLE_H_
#define HEXGYM_NATIVE_MBL_TABLE_H_

#include <stdexcept>
#include <string>
#include <vector>

#include "plugin_interface.h"  // kTableFormatVersion

namespace hexgym {

// A table file that cannot be used; what() names the file and the problem.
class TableError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

class MblTable {
 public:
  // Read `path`, checking (as hexgym.mbl.table.load_table does) format version, table name, input names
  // (in order), output name, shapes, dtypes, the content hash and finite values.
  MblTable(const std::string& path, const std::string& name, const std::vector<std::string>& inputs,
           const std::string& output);

  // The interpolated output at the query x (length d); x must be finite.
  double operator()(const double* x) const;

  int dims() const { return d_; }
  double axis_lo(int j) const { return axes_[j].lo; }
  double axis_hi(int j) const { return axes_[j].hi; }
  const std::vector<double>& axis_nodes(int j) const { return axes_[j].nodes; }
  const std::vector<double>& values() const { return values_; }  // C order

 private:
  struct Axis {
    double lo, hi, inv_step;
    long imax, stride;
    bool uniform;
    std::vector<double> nodes;
  };
  int d_ = 0;
  std::vector<Axis> axes_;
  std::vector<long> corner_offsets_;  // 2^d, last axis = lowest bit
  std::vector<double> values_;        // C order
};

}  // namespace hexgym

#endif  // HEXGYM_NATIVE_MBL_TABLE_H_
