// Reading the arrays of a NumPy .npz archive (np.savez / np.savez_compressed): a zip file of
// .npy members, stored or deflated, possibly with zip64 records (NumPy writes them).
#ifndef HEXGYM_NATIVE_NPZ_H_
#define HEXGYM_NATIVE_NPZ_H_

#include <map>
#include <stdexcept>
#include <string>
#include <vector>

namespace hexgym {

// Any problem with a file; what() says what is wrong (the caller adds the file name).
class NpzError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// One .npy array: little-endian float64 ('<f8') or a unicode string array ('<U').
struct NpyArray {
  std::vector<long> shape;
  std::vector<double> f8;            // the values, C order, if descr is '<f8'
  std::vector<std::string> strings;  // the elements, if descr is '<U<n>' (ASCII only)
  std::string descr;
};

// Name (without ".npy") -> array, for every member of the archive at `path`.
std::map<std::string, NpyArray> ReadNpz(const std::string& path);

}  // namespace hexgym

#endif  // HEXGYM_NATIVE_NPZ_H_
