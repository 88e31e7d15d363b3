// Model (Sep, d=1, p=2) of Hanebeck & Czado, Sec. IV, model 4:
//   z_t = a x_{t,1} + b x_{t,2} + sqrt(1 - a^2 - b^2) eps_t,
//   x_{t,1} = c x_{t-1,1} + sqrt(1 - c^2) eta_{t,1},
//   x_{t,2} = d x_{t-1,2} + sqrt(1 - d^2) eta_{t,2},
// eps_t, eta_t iid standard normal.  Log posterior pi(Theta | z) of
// Theta = (a, b, c, d, x0, x_1..x_T) as in Sec. IV, model 4: flat priors
// on a, b, c, d over their prior intervals (Eq. (3) for the restricted
// prior), restricted to a^2 + b^2 < 1 and |c|, |d| < 1, and a flat, improper
// prior on x0.
//
// The constraint a^2 + b^2 < 1 is built into the bounds: a lives in its
// prior interval cut to |a| < sqrt(1 - g^2), g the distance from 0 to
// b's prior interval (so some b fits), and b in its prior interval cut to
// |b| < sqrt(1 - a^2).  Stan's Jacobian for these a-dependent bounds
// keeps the density on (a, b) flat over the whole region, and the model
// block (log_prob without Jacobian) needs no extra term.
//
// States: x[t] is the row (x_{t,1}, x_{t,2}); read row-major, x gives the
// time-major order x_{1,1}, x_{1,2}, x_{2,1}, ... of Theta.
data {
  int<lower=1> T;  // number of time steps
  vector[T] z;  // observations z_1..z_T
  real a_lower;  // lower bound of the flat prior on a (may be -inf)
  real<lower=a_lower> a_upper;  // upper bound of that prior (may be +inf)
  real b_lower;  // lower bound of the flat prior on b (may be -inf)
  real<lower=b_lower> b_upper;  // upper bound of that prior (may be +inf)
  real c_lower;  // lower bound of the flat prior on c (may be -inf)
  real<lower=c_lower> c_upper;  // upper bound of that prior (may be +inf)
  real d_lower;  // lower bound of the flat prior on d (may be -inf)
  real<lower=d_lower> d_upper;  // upper bound of that prior (may be +inf)
}
transformed data {
  real b_gap = fmax(0, fmax(b_lower, -b_upper));  // min |b| over b's prior
  real a_max = sqrt(1 - square(b_gap));  // |a| < a_max leaves room for b
  real a_lo = fmax(a_lower, -a_max);  // support of a: prior interval
  real a_hi = fmin(a_upper, a_max);  // intersected with (-a_max, a_max)
  real c_lo = fmax(c_lower, -1);  // support of c: prior interval
  real c_hi = fmin(c_upper, 1);  // intersected with (-1, 1)
  real d_lo = fmax(d_lower, -1);  // support of d: prior interval
  real d_hi = fmin(d_upper, 1);  // intersected with (-1, 1)
  if (!(b_gap < 1 && a_lo < a_hi)) {
    reject("empty support for (a, b) with a^2 + b^2 < 1");
  }
  if (!(c_lo < c_hi)) {
    reject("empty support for c: (", c_lo, ", ", c_hi, ")");
  }
  if (!(d_lo < d_hi)) {
    reject("empty support for d: (", d_lo, ", ", d_hi, ")");
  }
}
parameters {
  real<lower=a_lo, upper=a_hi> a;  // loading of the first state
  real<lower=fmax(b_lower, -sqrt(1 - square(a))),
       upper=fmin(b_upper, sqrt(1 - square(a)))> b;  // of the second state
  real<lower=c_lo, upper=c_hi> c;  // AR coefficient of the first state
  real<lower=d_lo, upper=d_hi> d;  // AR coefficient of the second state
  vector[2] x0;  // initial state x_0
  matrix[T, 2] x;  // states: row t is x_t = (x_{t,1}, x_{t,2})
}
model {
  matrix[T, 2] x_prev = append_row(x0', x[1:(T - 1)]);  // x_0..x_{T-1}
  z ~ normal(x * [a, b]', sqrt(1 - square(a) - square(b)));
  col(x, 1) ~ normal(c * col(x_prev, 1), sqrt(1 - square(c)));
  col(x, 2) ~ normal(d * col(x_prev, 2), sqrt(1 - square(d)));
}
