// ssmobs: stands in for httpstan's stan/model/gradient.hpp (same include guard, same two
// overloads, same results).  The native backend puts this directory on the include path
// before httpstan's (ssmobs.stan_backends.native_build), so Stan's own file is never read.
//
// What differs: the overload with a logger, which the NUTS sampler calls once per leapfrog
// step (base_hamiltonian::update_potential_gradient), wrote the model's messages into a
// std::stringstream constructed for every call and copied its text twice to test whether
// anything was written.  Here one stream per thread is reused: emptied (text, state flags,
// formatting) before each call, tested without a copy.  What reaches the logger, when, and
// which exception propagates are as in Stan's file.  The gradient is computed as
// stan::math::gradient does, with two costs per call fewer: the independent variables are
// not put on the chain stack (their chain() does nothing, so the same nodes are chained in
// the same order and every number is unchanged), and their vector is one per thread,
// reused (no heap allocation).
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

// As stan::math::gradient(model_functional<M>(model, msgs), x, f, grad_f), with the
// independent variables off the chain stack (their chain() does nothing) and their
// vector reused per thread: the same nodes are chained in the same order.
template <class M>
inline void gradient_unstacked(const M& model, const Eigen::Matrix<double, Eigen::Dynamic, 1>& x,
                               double& f, Eigen::Matrix<double, Eigen::Dynamic, 1>& grad_f,
                               std::ostream* msgs) {
  using stan::math::var;
  using stan::math::vari;
  thread_local Eigen::Matrix<var, Eigen::Dynamic, 1> x_var;
  stan::math::nested_rev_autodiff nested;
  x_var.resize(x.size());
  for (Eigen::Index i = 0; i < x.size(); ++i)
    x_var.coeffRef(i) = var(new vari(x.coeff(i), false));
  var fx_var = model.template log_prob<true, true>(x_var, msgs);
  f = fx_var.val();
  grad_f.resize(x.size());
  stan::math::grad(fx_var.vi_);
  for (Eigen::Index i = 0; i < x.size(); ++i)
    grad_f.coeffRef(i) = x_var.coeff(i).adj();
}

}  // namespace ssmobs_detail

template <class M>
void gradient(const M& model, const Eigen::Matrix<double, Eigen::Dynamic, 1>& x,
              double& f, Eigen::Matrix<double, Eigen::Dynamic, 1>& grad_f,
              callbacks::logger& logger) {
  std::stringstream& messages = ssmobs_detail::fresh_message_stream();
  try {
    ssmobs_detail::gradient_unstacked(model, x, f, grad_f, &messages);
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
