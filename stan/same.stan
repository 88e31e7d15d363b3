// Model (Same, d=p=1) of Hanebeck & Czado, Sec. IV, model 1; Eq. (5):
//   z_t = a x_t + sqrt(1 - a^2) eps_t,
//   x_t = a x_{t-1} + sqrt(1 - a^2) eta_t,   eps_t, eta_t ~ N(0, 1) iid.
// Log posterior pi(Theta | z) of Theta = (a, x0, x_1..x_T) as in Sec. IV,
// model 1 (the log of Eq. (6)): flat prior on a over (a_lower, a_upper)
// intersected with (-1, 1) (Eq. (3) for the restricted prior) and a flat,
// improper prior on x0.
data {
  int<lower=1> T;  // number of time steps
  vector[T] z;  // observations z_1..z_T
  real a_lower;  // lower bound of the flat prior on a (may be -inf)
  real<lower=a_lower> a_upper;  // upper bound of that prior (may be +inf)
}
transformed data {
  real a_lo = fmax(a_lower, -1);  // support of a: prior interval
  real a_hi = fmin(a_upper, 1);  // intersected with (-1, 1)
  if (!(a_lo < a_hi)) {
    reject("empty support for a: (", a_lo, ", ", a_hi, ")");
  }
}
parameters {
  real<lower=a_lo, upper=a_hi> a;  // AR coefficient, states and observations
  real x0;  // initial state x_0
  vector[T] x;  // states x_1..x_T
}
model {
  real s = sqrt(1 - square(a));  // disturbance scale sqrt(1 - a^2)
  z ~ normal(a * x, s);
  x ~ normal(a * append_row(x0, head(x, T - 1)), s);
}
