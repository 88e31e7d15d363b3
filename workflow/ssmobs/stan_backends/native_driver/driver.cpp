// ssmobs native Stan driver: one process runs NUTS (diag_e metric, adapted) for one
// data set, with the same service call and arguments as CmdStan and PyStan, and writes
// the post-warmup draws in a binary layout NumPy reads without parsing.
//
// Compiled once into an object file and linked with each stanc-generated model's own
// object file (which defines new_model) by ssmobs.stan_backends.native.  Usage:
//
//   driver --data data.json --output draws.bin --seed S --chains C --warmup W
//          --samples N --delta D --max-depth M [--init init.json ...] [--threads K]
//          [--init-radius R] [--parent-pid P] [--discard]
//   driver --log-density [--sampler-gradient] [--autodiff-twin] --data data.json
//          --output values.txt --init point.json ...
//
// With --log-density no sampling is done: for every --init file (a point on the
// constrained scale, Stan JSON) the driver writes the model block's log density without
// Jacobian and without dropping constants, and its gradient on the unconstrained scale,
// or that the model rejects the point.  Text output, one line each:
//   "param <name> <dim>..."  for every parameter, in the program's order, then per point
//   "ok <log density> <gradient>..."  or  "rejected <Stan's message on one line>".
// With --sampler-gradient the log density and gradient are instead those the NUTS sampler
// uses (stan::model::gradient: Jacobian included, constants dropped).  With --autodiff-twin
// a program holding both model blocks (ssmobs.nuts.analytic_program) evaluates its
// hand-written one under Stan's autodiff instead of the generated function
// (ssmobs/gradient_slot.hpp); sampling always runs the generated function.
//
// Output, little-endian whatever the host: "SSMOBSD1" (8 bytes), uint32 header length L,
// L bytes of header text "byteorder=little\nchains=C\ndraws=N\ncolumns=name1,name2,...\n",
// then for every chain in order its N rows of len(columns) IEEE-754 float64 values
// (row-major).  With --discard nothing is written (the sampler's floor, for benchmarks).
//
// With --parent-pid P (the caller's pid), on Linux the driver asks to be killed when its
// parent dies (PR_SET_PDEATHSIG) and exits at once if P is already gone.
//
// Exit codes: 0 ok; 2 bad arguments; 3 the sampler failed on these data (initialisation
// failed, exception in the model); 4 the data were rejected by the model's constructor;
// 5 the output could not be written; 6 a data or init file cannot be opened or is not
// valid Stan JSON (an environment failure, not a property of the data); 7 the parent
// given by --parent-pid was already gone.

#include <stan/model/model_base.hpp>
#include <stan/callbacks/interrupt.hpp>
#include <stan/callbacks/logger.hpp>
#include <stan/callbacks/writer.hpp>
#include <stan/io/empty_var_context.hpp>
#include <stan/io/json/json_data.hpp>
#include <stan/model/gradient.hpp>
#if __has_include(<ssmobs/gradient_slot.hpp>)  // our headers (absent: Stan's own, for tests)
#include <ssmobs/gradient_slot.hpp>
#endif
#include <stan/model/log_prob_grad.hpp>
#include <stan/math/prim/core/init_threadpool_tbb.hpp>
#include <stan/services/sample/hmc_nuts_diag_e_adapt.hpp>

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cerrno>
#include <csignal>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iostream>
#include <limits>
#include <memory>
#include <mutex>
#include <sstream>
#include <string>
#include <vector>

#ifdef __linux__
#include <sys/prctl.h>
#include <unistd.h>
#endif

// Defined by the stanc-generated model (its own translation unit).
stan::model::model_base& new_model(stan::io::var_context& data_context, unsigned int seed,
                                   std::ostream* msg_stream);

static_assert(std::numeric_limits<double>::is_iec559 && sizeof(double) == 8,
              "the draws file holds IEEE-754 binary64 values");

namespace {

enum ExitCode {
  kOk = 0,
  kUsage = 2,
  kSamplerFailed = 3,
  kDataRejected = 4,
  kWriteFailed = 5,
  kInputUnreadable = 6,
  kOrphaned = 7,
};

std::mutex stderr_mutex;

// Sends Stan's messages to stderr, one line each, prefixed with the chain id.
class StderrLogger : public stan::callbacks::logger {
 public:
  explicit StderrLogger(int chain) : prefix_("chain " + std::to_string(chain) + ": ") {}
  void debug(const std::string& m) override {}
  void debug(const std::stringstream& m) override {}
  void info(const std::string& m) override { put("", m); }
  void info(const std::stringstream& m) override { put("", m.str()); }
  void warn(const std::string& m) override { put("warning: ", m); }
  void warn(const std::stringstream& m) override { put("warning: ", m.str()); }
  void error(const std::string& m) override { put("error: ", m); }
  void error(const std::stringstream& m) override { put("error: ", m.str()); }
  void fatal(const std::string& m) override { put("fatal: ", m); }
  void fatal(const std::stringstream& m) override { put("fatal: ", m.str()); }

 private:
  void put(const char* level, const std::string& m) {
    if (m.empty()) return;
    std::lock_guard<std::mutex> lock(stderr_mutex);
    std::cerr << prefix_ << level << m << '\n';
  }
  std::string prefix_;
};

// Keeps the column names and every row of numbers (post-warmup draws) in memory.
class RowWriter : public stan::callbacks::writer {
 public:
  void operator()(const std::vector<std::string>& names) override { names_ = names; }
  void operator()(const std::vector<double>& state) override {
    if (discard_) {
      ++n_rows_;
      return;
    }
    values_.insert(values_.end(), state.begin(), state.end());
    ++n_rows_;
  }
  bool discard_ = false;
  std::vector<std::string> names_;
  std::vector<double> values_;
  std::size_t n_rows_ = 0;
};

struct Args {
  std::string data, output;
  std::vector<std::string> inits;
  unsigned int seed = 0;
  long parent_pid = 0;
  int chains = 4, warmup = 1000, samples = 1000, max_depth = 10, threads = 1;
  double delta = 0.8, init_radius = 2.0;
  bool discard = false, log_density = false, sampler_gradient = false, twin = false;
};

[[noreturn]] void usage(const std::string& why) {
  std::cerr << "driver: " << why << "\n";
  std::exit(kUsage);
}

Args parse(int argc, char** argv) {
  Args a;
  for (int i = 1; i < argc; ++i) {
    std::string k = argv[i];
    if (k == "--discard") {
      a.discard = true;
      continue;
    }
    if (k == "--log-density") {
      a.log_density = true;
      continue;
    }
    if (k == "--sampler-gradient") {
      a.sampler_gradient = true;
      continue;
    }
    if (k == "--autodiff-twin") {
      a.twin = true;
      continue;
    }
    if (i + 1 >= argc) usage("missing value after " + k);
    std::string v = argv[++i];
    try {
      if (k == "--data") a.data = v;
      else if (k == "--output") a.output = v;
      else if (k == "--init") a.inits.push_back(v);
      else if (k == "--seed") a.seed = static_cast<unsigned int>(std::stoul(v));
      else if (k == "--chains") a.chains = std::stoi(v);
      else if (k == "--warmup") a.warmup = std::stoi(v);
      else if (k == "--samples") a.samples = std::stoi(v);
      else if (k == "--max-depth") a.max_depth = std::stoi(v);
      else if (k == "--threads") a.threads = std::stoi(v);
      else if (k == "--delta") a.delta = std::stod(v);
      else if (k == "--init-radius") a.init_radius = std::stod(v);
      else if (k == "--parent-pid") a.parent_pid = std::stol(v);
      else usage("unknown option " + k);
    } catch (const std::exception&) {
      usage("bad value for " + k + ": " + v);
    }
  }
  if (a.data.empty()) usage("--data is required");
  if (a.output.empty() && !a.discard) usage("--output (or --discard) is required");
  if (a.chains < 1 || a.samples < 1 || a.warmup < 0 || a.threads < 1 || a.max_depth < 1)
    usage("chains, samples, threads, max-depth must be >= 1 and warmup >= 0");
  if (a.log_density) {
    if (a.output.empty()) usage("--log-density needs --output");
  } else if (a.sampler_gradient || a.twin) {
    usage(a.twin ? "--autodiff-twin needs --log-density"
                 : "--sampler-gradient needs --log-density");
  }
  if (a.log_density) {
    a.chains = static_cast<int>(a.inits.size());
  } else if (!a.inits.empty() && static_cast<int>(a.inits.size()) != a.chains) {
    usage("give one --init per chain or none");
  }
  return a;
}

std::unique_ptr<stan::io::var_context> read_json(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error("cannot open " + path);
  return std::make_unique<stan::json::json_data>(in);
}

bool host_is_little_endian() {
  const std::uint32_t one = 1;
  unsigned char first;
  std::memcpy(&first, &one, 1);
  return first == 1;
}

// Writes n doubles as little-endian binary64 (as they are on a little-endian host).
bool write_doubles_le(std::FILE* f, const double* x, std::size_t n) {
  if (host_is_little_endian()) return std::fwrite(x, sizeof(double), n, f) == n;
  unsigned char buf[8 * 512];
  for (std::size_t i = 0; i < n;) {
    const std::size_t m = std::min<std::size_t>(512, n - i);
    for (std::size_t k = 0; k < m; ++k) {
      std::uint64_t bits;
      std::memcpy(&bits, &x[i + k], 8);
      for (int b = 0; b < 8; ++b) buf[8 * k + b] = static_cast<unsigned char>(bits >> (8 * b));
    }
    if (std::fwrite(buf, 8, m, f) != m) return false;
    i += m;
  }
  return true;
}

bool write_output(const std::string& path, const std::vector<RowWriter>& writers,
                  int samples) {
  std::ostringstream header;
  header << "byteorder=little\nchains=" << writers.size() << "\ndraws=" << samples
         << "\ncolumns=";
  const auto& names = writers[0].names_;
  for (std::size_t j = 0; j < names.size(); ++j) header << (j ? "," : "") << names[j];
  header << "\n";
  const std::string text = header.str();
  if (text.size() > std::numeric_limits<std::uint32_t>::max()) return false;
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) return false;
  const std::uint32_t len = static_cast<std::uint32_t>(text.size());
  const unsigned char len_le[4] = {
      static_cast<unsigned char>(len), static_cast<unsigned char>(len >> 8),
      static_cast<unsigned char>(len >> 16), static_cast<unsigned char>(len >> 24)};
  bool ok = std::fwrite("SSMOBSD1", 1, 8, f) == 8 && std::fwrite(len_le, 1, 4, f) == 4 &&
            std::fwrite(text.data(), 1, text.size(), f) == text.size();
  for (const auto& w : writers) {
    if (!ok) break;
    ok = write_doubles_le(f, w.values_.data(), w.values_.size());
  }
  ok = (std::fclose(f) == 0) && ok;
  return ok;
}

std::string one_line(std::string text) {
  std::replace(text.begin(), text.end(), '\n', ' ');
  return text;
}

// --log-density: the log density and gradient at every point (see the file's header).
int write_log_densities(const stan::model::model_base& model,
                        const std::vector<std::unique_ptr<stan::io::var_context>>& points,
                        const std::string& path, bool sampler_gradient) {
  std::ostringstream out;
  out.precision(17);
  std::vector<std::string> names;
  std::vector<std::vector<size_t>> dims;
  model.get_param_names(names, false, false);
  model.get_dims(dims, false, false);
  for (std::size_t j = 0; j < names.size(); ++j) {
    out << "param " << names[j];
    for (auto n : dims[j]) out << ' ' << n;
    out << '\n';
  }
  for (const auto& point : points) {
    std::vector<double> params_r, gradient;
    std::vector<int> params_i;
    std::ostringstream msgs;
    try {
      model.transform_inits(*point, params_i, params_r, &msgs);
      double lp;
      if (sampler_gradient) {
        Eigen::VectorXd q = Eigen::Map<Eigen::VectorXd>(params_r.data(), params_r.size());
        Eigen::VectorXd g;
        stan::callbacks::logger quiet;
        stan::model::gradient(model, q, lp, g, quiet);
        gradient.assign(g.data(), g.data() + g.size());
      } else {
        lp = stan::model::log_prob_grad<false, false>(model, params_r, params_i, gradient,
                                                      &msgs);
      }
      out << "ok " << lp;
      for (double g : gradient) out << ' ' << g;
      out << '\n';
    } catch (const std::exception& e) {
      out << "rejected " << one_line(e.what()) << '\n';
    }
  }
  std::ofstream file(path);
  file << out.str();
  file.close();
  return file ? kOk : kWriteFailed;
}

}  // namespace

int main(int argc, char** argv) {
  const Args a = parse(argc, argv);

#ifdef __linux__
  if (a.parent_pid > 0) {
    // Die with the parent (SIGKILL when the thread that started us ends), and do not
    // start sampling if it is gone already (we would have been reparented).
    prctl(PR_SET_PDEATHSIG, SIGKILL);
    if (static_cast<long>(getppid()) != a.parent_pid) {
      std::cerr << "driver: parent process " << a.parent_pid << " is gone\n";
      return kOrphaned;
    }
  }
#endif

  // Reading the JSON files: a failure is the environment's (a file that is gone, not
  // valid JSON), never the model's judgement of the data.
  std::unique_ptr<stan::io::var_context> data;
  std::vector<std::unique_ptr<stan::io::var_context>> inits;
  std::string reading = a.data;
  try {
    data = read_json(a.data);
    for (int c = 0; c < a.chains; ++c) {
      if (a.inits.empty()) {
        inits.emplace_back(std::make_unique<stan::io::empty_var_context>());
      } else {
        reading = a.inits[c];
        inits.emplace_back(read_json(a.inits[c]));
      }
    }
  } catch (const std::exception& e) {
    std::cerr << "cannot read " << reading << ": " << e.what() << "\n";
    return kInputUnreadable;
  }

  std::unique_ptr<stan::model::model_base> model;
  try {
    model.reset(&new_model(*data, a.seed, &std::cerr));
  } catch (const std::exception& e) {
    std::cerr << "data rejected: " << e.what() << "\n";
    return kDataRejected;
  }

#ifdef SSMOBS_GRADIENT_SLOT_HPP
  ssmobs::autodiff_twin() = a.twin;
#else
  if (a.twin) usage("--autodiff-twin needs ssmobs/gradient_slot.hpp on the include path");
#endif
  if (a.log_density) {
    const int code = write_log_densities(*model, inits, a.output, a.sampler_gradient);
    if (code != kOk) std::cerr << "cannot write " << a.output << ": " << std::strerror(errno) << "\n";
    return code;
  }

  std::vector<RowWriter> writers(a.chains);
  for (auto& w : writers) {
    w.discard_ = a.discard;
    if (!a.discard) w.values_.reserve(static_cast<std::size_t>(a.samples) * 256);
  }
  std::vector<int> codes(a.chains, 0);
  std::vector<std::string> failures(a.chains);

  auto run_chain = [&](int c) {
    StderrLogger logger(c + 1);
    stan::callbacks::interrupt interrupt;
    stan::callbacks::writer init_writer, diagnostic_writer;
    try {
      // Chain ids 1..C with one seed, the sampler defaults of CmdStan and PyStan.
      codes[c] = stan::services::sample::hmc_nuts_diag_e_adapt(
          *model, *inits[c], a.seed, static_cast<unsigned int>(c + 1), a.init_radius,
          a.warmup, a.samples, /*num_thin=*/1, /*save_warmup=*/false, /*refresh=*/0,
          /*stepsize=*/1.0, /*stepsize_jitter=*/0.0, a.max_depth, a.delta,
          /*gamma=*/0.05, /*kappa=*/0.75, /*t0=*/10.0, /*init_buffer=*/75,
          /*term_buffer=*/50, /*window=*/25, interrupt, logger, init_writer, writers[c],
          diagnostic_writer);
    } catch (const std::exception& e) {
      codes[c] = -1;
      failures[c] = e.what();
    }
  };

  if (a.threads <= 1) {
    for (int c = 0; c < a.chains; ++c) run_chain(c);
  } else {
    stan::math::init_threadpool_tbb(a.threads);
    tbb::parallel_for(0, a.chains, 1, run_chain);
  }

  for (int c = 0; c < a.chains; ++c) {
    if (codes[c] != 0) {
      std::cerr << "chain " << c + 1 << " failed"
                << (failures[c].empty() ? "" : ": " + failures[c]) << "\n";
      return kSamplerFailed;
    }
    if (writers[c].n_rows_ != static_cast<std::size_t>(a.samples)) {
      std::cerr << "chain " << c + 1 << " wrote " << writers[c].n_rows_ << " draws, "
                << "expected " << a.samples << "\n";
      return kSamplerFailed;
    }
  }
  if (!a.discard && !write_output(a.output, writers, a.samples)) {
    std::cerr << "cannot write " << a.output << ": " << std::strerror(errno) << "\n";
    return kWriteFailed;
  }
  return kOk;
}
