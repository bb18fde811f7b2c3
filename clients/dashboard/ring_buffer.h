// A fixed-capacity ring buffer: pushing onto a full buffer overwrites the oldest element.
// The dashboard keeps each actuator's recent (decimated) points in one, so memory per
// actuator is bounded however long the service runs.
#pragma once

#include <cstddef>
#include <stdexcept>
#include <vector>

namespace flexid::dashboard {

template <typename T>
class RingBuffer {
 public:
  explicit RingBuffer(size_t capacity) : slots_(capacity) {
    if (capacity == 0) throw std::invalid_argument("RingBuffer: capacity must be > 0");
  }

  void Push(T value) {
    slots_[(first_ + size_) % slots_.size()] = std::move(value);
    if (size_ < slots_.size())
      ++size_;
    else
      first_ = (first_ + 1) % slots_.size();
  }

  void Clear() {
    first_ = 0;
    size_ = 0;
  }

  // Element i, oldest first (0 <= i < size()).
  const T& operator[](size_t i) const { return slots_[(first_ + i) % slots_.size()]; }
  const T& Back() const { return (*this)[size_ - 1]; }

  size_t size() const { return size_; }
  size_t capacity() const { return slots_.size(); }
  bool empty() const { return size_ == 0; }

 private:
  std::vector<T> slots_;
  size_t first_ = 0;  // index of the oldest element
  size_t size_ = 0;
};

}  // namespace flexid::dashboard
