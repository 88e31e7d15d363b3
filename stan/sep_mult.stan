// Model (Sep, d=p=1, Multiplicative) of Hanebeck & Czado, Sec. IV,
// model 6:
//   z_t = sqrt(a) x_t eps_t,   x_t = a + x_{t-1} + eta_t,   a > 0,
// eps_t, eta_t ~ N(0, 1) iid.  Log posterior pi(Theta | z) of
// Theta = (a, x0, x_1..x_T) as in Sec. IV, model 6: flat prior on a over
// (a_lower, a_upper) intersected with (0, inf) (the half line of Eq. (14)
// or Eq. (3)) and a flat, improper prior on x0.
data {
  int<lower=1> T;  // number of time steps
  vector[T] z;  // observations z_1..z_T
  real a_lower;  // lower bound of the flat prior on a (may be -inf)
  real<lower=a_lower> a_upper;  // upper bound of that prior (may be +inf)
}
transformed data {
  real a_lo = fmax(a_lower, 0);  // support of a: prior interval and a > 0
  if (!(a_lo < a_upper)) {
    reject("empty support for a: (", a_lo, ", ", a_upper, ")");
  }
}
parameters {
  real<lower=a_lo, upper=a_upper> a;  // drift and observation variance
  real x0;  // initial state x_0
  vector[T] x;  // states x_1..x_T
}
model {
  // z_t | x_t ~ N(0, a x_t^2): -log(sqrt(a) |x_t|) - z_t^2 / (2 a x_t^2)
  z ~ normal(0, sqrt(a) * abs(x));
  x ~ normal(a + append_row(x0, head(x, T - 1)), 1);
}
