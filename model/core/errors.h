// Error raised for bad outside input (files, arguments). Its message is one line that
// names the input and the problem, e.g. "run3.csv:14:2: time is not increasing (12.5 after 12.6)".
#pragma once

#include <stdexcept>

namespace flexid::model {

struct InputError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

}  // namespace flexid::model
