// ssmobs: stands in for httpstan's stan/model/gradient.hpp (same include guard, same two
// overloads, same results).  The native backend puts this directory on the include path
// before httpstan's (ssmobs.stan_backends.native_build), so Stan's own file is never read.
//
// What differs: the overload with a logger, which the NUTS sampler calls once per leapfrog
// step (base_hamiltonian::update_potential_gradient), wrote the model's messages into a
// std::stringstream constructed for every call and copied its text twice to test whether
// anything was written.  Here one stream per thread is reused: emptied (text, state flags,
// formatting) before each call, tested without a copy.  What reaches the logger, when, and
// which exception propagates are as in Stan's file; the gradient is computed by the same
// call, so every number is unchanged.
#ifndef STAN_MODEL_GRADIENT_HPP
#define STAN_MODEL_GRADIENT_HPP

#include <stan/callbacks/logger.hpp>
#include <stan/callbacks/writer.hpp>
#include <stan/math/rev.hpp>
#include <stan/model/model_functional.hpp>
#include <ios>
#include <sstream>
#include <stdexcept>
#include <string>

namespace stan {
namespace model {

template <class M>
void gradient(const M& model, const Eigen::Matrix<double, Eigen::Dynamic, 1>& x,
              double& f, Eigen::Matrix<double, Eigen::Dynamic, 1>& grad_f,
              std::ostream* msgs = 0) {
  stan::math::gradient(model_functional<M>(model, msgs), x, f, grad_f);
}

namespace ssmobs_detail {

// This thread's message stream, empty and in the state of a newly constructed one.
inline std::stringstream& fresh_message_stream() {
  thread_local std::stringstream stream;
  stream.str(std::string());
  stream.clear();
  stream.flags(std::ios_base::skipws | std::ios_base::dec);
  stream.precision(6);
  stream.width(0);
  stream.fill(stream.widen(' '));
  return stream;
}

// Whether anything was written since fresh_message_stream(); reads no text.
inline bool has_message(std::stringstream& stream) {
  return stream.rdbuf()->in_avail() > 0;
}

}  // namespace ssmobs_detail

template <class M>
void gradient(const M& model, const Eigen::Matrix<double, Eigen::Dynamic, 1>& x,
              double& f, Eigen::Matrix<double, Eigen::Dynamic, 1>& grad_f,
              callbacks::logger& logger) {
  std::stringstream& messages = ssmobs_detail::fresh_message_stream();
  try {
    stan::math::gradient(model_functional<M>(model, &messages), x, f, grad_f);
  } catch (std::exception&) {
    if (ssmobs_detail::has_message(messages))
      logger.info(messages);
    throw;
  }
  if (ssmobs_detail::has_message(messages))
    logger.info(messages);
}

}  // namespace model
}  // namespace stan
#endif
