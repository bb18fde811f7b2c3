#include "model/core/levels.h"

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <cstdint>
#include <functional>
#include <iostream>
#include <limits>
#include <numbers>
#include <random>
#include <string>
#include <vector>

#include "model/core/errors.h"

namespace flexid::model {
namespace {

// Standard normal draws by Box-Muller on std::mt19937_64, whose output sequence the C++
// standard fixes, so the noise is the same with every standard library.
class Gaussian {
 public:
  explicit Gaussian(uint64_t seed) : engine_(seed) {}
  double Uniform() {  // (0, 1)
    return (static_cast<double>(engine_() >> 11) + 0.5) * 0x1.0p-53;
  }
  double operator()() {
    return std::sqrt(-2 * std::log(Uniform())) * std::cos(2 * std::numbers::pi * Uniform());
  }

 private:
  std::mt19937_64 engine_;
};

struct Signal {
  std::vector<double> t_s, voltage_V;
};

// Uniform sampling t_k = k / rate (division keeps whole seconds exact) with voltage
// given per sample index.
Signal Sampled(size_t n, double rate_Hz, const std::function<double(size_t)>& voltage_V) {
  Signal s;
  for (size_t k = 0; k < n; ++k) {
    s.t_s.push_back(static_cast<double>(k) / rate_Hz);
    s.voltage_V.push_back(voltage_V(k));
  }
  return s;
}

// Blocks of `block` samples holding the given voltages in turn.
Signal Blocks(const std::vector<double>& block_V, size_t block, double rate_Hz = 10.0) {
  return Sampled(block_V.size() * block, rate_Hz, [&](size_t k) { return block_V[k / block]; });
}

// Square wave between 0 and level_V at 10 Hz, period 220 s, 50 % duty, `periods` periods;
// rest first when rest_first, else the level first.
Signal SquareWave(double level_V, int periods, bool rest_first = true) {
  const size_t half = 1100;
  return Sampled(2 * half * static_cast<size_t>(periods), 10.0, [=](size_t k) {
    const bool high = ((k / half) % 2 == 0) != rest_first;
    return high ? level_V : 0.0;
  });
}

void AddNoise(Signal* s, double sigma_V, uint64_t seed) {
  Gaussian normal(seed);
  for (double& v : s->voltage_V) v += sigma_V * normal();
}

// The message of the InputError that DetectLevels throws ("" if none).
std::string DetectError(const Signal& s, const LevelDetectionOptions& options = {}) {
  try {
    DetectLevels(s.t_s, s.voltage_V, options);
  } catch (const InputError& error) {
    return error.what();
  }
  return "";
}

void ExpectSegment(const LevelSegment& segment, size_t begin, size_t fit_begin, size_t end,
                   size_t recording = 0) {
  EXPECT_EQ(segment.begin, begin);
  EXPECT_EQ(segment.fit_begin, fit_begin);
  EXPECT_EQ(segment.end, end);
  EXPECT_EQ(segment.recording, recording);
}

TEST(Levels, OptionsValidation) {
  std::string error;
  EXPECT_TRUE(LevelDetectionOptions{}.IsValid(&error));
  LevelDetectionOptions options;
  options.min_hold_s = 0;
  EXPECT_FALSE(options.IsValid(&error));
  EXPECT_NE(error.find("min_hold_s"), std::string::npos);
  options = {};
  options.tolerance_V = -1;
  EXPECT_FALSE(options.IsValid(nullptr));
  options = {};
  options.rest_band_V = NAN;
  EXPECT_FALSE(options.IsValid(&error));
  EXPECT_NE(error.find("rest_band_V"), std::string::npos);
  options = {};
  options.lead_in_s = INFINITY;
  EXPECT_FALSE(options.IsValid(&error));
  options = {};
  options.max_glitch_samples = -1;
  EXPECT_FALSE(options.IsValid(&error));
  const Signal s = SquareWave(5, 1);
  EXPECT_THROW(DetectLevels(s.t_s, s.voltage_V, options), std::invalid_argument);
}

TEST(Levels, SquareWaveIsOneLevelWithOneSegmentOverTheWholeRecording) {
  for (bool rest_first : {true, false}) {
    const Signal s = SquareWave(5.0, 5, rest_first);
    const LevelAnalysis a = DetectLevels(s.t_s, s.voltage_V);
    EXPECT_TRUE(a.plateau_input);
    ASSERT_EQ(a.levels.size(), 1u);
    EXPECT_DOUBLE_EQ(a.levels[0].level_V, 5.0);
    ASSERT_EQ(a.levels[0].segments.size(), 1u);
    ExpectSegment(a.levels[0].segments[0], 0, 0, 11000);
    // Ten half-periods of 1100 samples, alternating rest and level.
    ASSERT_EQ(a.plateaus.size(), 10u);
    for (size_t i = 0; i < 10; ++i) {
      const bool high = (i % 2 == 0) != rest_first;
      EXPECT_EQ(a.plateaus[i].begin, 1100 * i);
      EXPECT_EQ(a.plateaus[i].end, 1100 * (i + 1));
      EXPECT_DOUBLE_EQ(a.plateaus[i].t_start_s, 110.0 * static_cast<double>(i));
      EXPECT_DOUBLE_EQ(a.plateaus[i].t_end_s, 110.0 * static_cast<double>(i + 1) - 0.1);
      EXPECT_DOUBLE_EQ(a.plateaus[i].voltage_V, high ? 5.0 : 0.0);
      EXPECT_EQ(a.plateaus[i].level, high ? 0 : -1);
    }
    // Noise-free: the tolerance is the floor, 1e-3 of the 5 V range.
    EXPECT_DOUBLE_EQ(a.tolerance_V, 5e-3);
  }
}

TEST(Levels, StaircaseGivesOneLevelPerStepWithLeadIns) {
  // 0 -> 2 -> 4 -> 6 -> 8 V, 150 s each at 10 Hz: plateaus of 1500 samples.
  const Signal s = Blocks({0, 2, 4, 6, 8}, 1500);
  const LevelAnalysis a = DetectLevels(s.t_s, s.voltage_V);
  EXPECT_TRUE(a.plateau_input);
  ASSERT_EQ(a.levels.size(), 4u);
  for (size_t i = 0; i < 4; ++i) {
    EXPECT_DOUBLE_EQ(a.levels[i].level_V, 2.0 * static_cast<double>(i + 1));
    ASSERT_EQ(a.levels[i].segments.size(), 1u);
  }
  // The initial rest belongs to the following (first) level; every later segment starts
  // with 20 s = 200 samples of the preceding plateau.
  ExpectSegment(a.levels[0].segments[0], 0, 0, 3000);
  ExpectSegment(a.levels[1].segments[0], 2800, 3000, 4500);
  ExpectSegment(a.levels[2].segments[0], 4300, 4500, 6000);
  ExpectSegment(a.levels[3].segments[0], 5800, 6000, 7500);
  ASSERT_EQ(a.plateaus.size(), 5u);
  EXPECT_EQ(a.plateaus[0].level, -1);
  for (int i = 1; i < 5; ++i) EXPECT_EQ(a.plateaus[static_cast<size_t>(i)].level, i - 1);

  // A shorter lead-in, and none at all.
  LevelDetectionOptions options;
  options.lead_in_s = 5.0;
  const LevelAnalysis short_lead = DetectLevels(s.t_s, s.voltage_V, options);
  ExpectSegment(short_lead.levels[1].segments[0], 2950, 3000, 4500);
  options.lead_in_s = 0.0;
  const LevelAnalysis no_lead = DetectLevels(s.t_s, s.voltage_V, options);
  ExpectSegment(no_lead.levels[3].segments[0], 6000, 6000, 7500);
  // A lead-in longer than the preceding plateau stops at that plateau's start.
  options.lead_in_s = 1000.0;
  const LevelAnalysis long_lead = DetectLevels(s.t_s, s.voltage_V, options);
  ExpectSegment(long_lead.levels[1].segments[0], 1500, 3000, 4500);
}

TEST(Levels, RestAfterAnExcitationBelongsToThatLevel) {
  // 0, 2, 0, 4, 0 V blocks of 100 s: the rest after 2 V is 2 V's relaxation.
  const Signal s = Blocks({0, 2, 0, 4, 0}, 1000);
  const LevelAnalysis a = DetectLevels(s.t_s, s.voltage_V);
  ASSERT_EQ(a.levels.size(), 2u);
  ASSERT_EQ(a.levels[0].segments.size(), 1u);
  ASSERT_EQ(a.levels[1].segments.size(), 1u);
  ExpectSegment(a.levels[0].segments[0], 0, 0, 3000);
  ExpectSegment(a.levels[1].segments[0], 2800, 3000, 5000);
}

TEST(Levels, NegativeAndPositiveLevelsAreDistinct) {
  const Signal s = Blocks({0, 5, 0, -5, 0, 5, 0, -5}, 1000);
  const LevelAnalysis a = DetectLevels(s.t_s, s.voltage_V);
  ASSERT_EQ(a.levels.size(), 2u);
  EXPECT_DOUBLE_EQ(a.levels[0].level_V, -5.0);
  EXPECT_DOUBLE_EQ(a.levels[1].level_V, 5.0);
  ASSERT_EQ(a.levels[0].segments.size(), 2u);
  ASSERT_EQ(a.levels[1].segments.size(), 2u);
  ExpectSegment(a.levels[1].segments[0], 0, 0, 3000);
  ExpectSegment(a.levels[0].segments[0], 2800, 3000, 5000);
  ExpectSegment(a.levels[1].segments[1], 4800, 5000, 7000);
  ExpectSegment(a.levels[0].segments[1], 6800, 7000, 8000);

  // A bipolar square wave without rest: two levels, alternating segments.
  const Signal bipolar = Blocks({-3, 3, -3, 3}, 1000);
  const LevelAnalysis b = DetectLevels(bipolar.t_s, bipolar.voltage_V);
  ASSERT_EQ(b.levels.size(), 2u);
  EXPECT_DOUBLE_EQ(b.levels[0].level_V, -3.0);
  EXPECT_DOUBLE_EQ(b.levels[1].level_V, 3.0);
  ExpectSegment(b.levels[0].segments[0], 0, 0, 1000);
  ExpectSegment(b.levels[1].segments[0], 800, 1000, 2000);
}

TEST(Levels, NoiseAndSpikesDoNotSplitPlateaus) {
  Signal s = SquareWave(5.0, 5);
  AddNoise(&s, 0.010, 42);
  // Single-sample spikes every 97 samples away from the edges, alternating +3 V and a
  // dropout to 0 V (on a rest plateau: to -3 V), plus one 3-sample and one 5-sample burst.
  for (size_t k = 0; k < s.voltage_V.size(); ++k) {
    const size_t phase = k % 1100;
    if (k % 97 != 0 || phase < 50 || phase > 1050) continue;
    const double base = s.voltage_V[k];
    s.voltage_V[k] = (k / 97) % 2 == 0 ? base + 3.0 : (base > 2.5 ? 0.0 : -3.0);
  }
  for (size_t k = 1500; k < 1503; ++k) s.voltage_V[k] = 9.0;
  for (size_t k = 5600; k < 5605; ++k) s.voltage_V[k] = 2.5;
  const LevelAnalysis a = DetectLevels(s.t_s, s.voltage_V);
  ASSERT_EQ(a.plateaus.size(), 10u);
  for (size_t i = 0; i < 10; ++i) {
    EXPECT_EQ(a.plateaus[i].begin, 1100 * i);
    EXPECT_EQ(a.plateaus[i].end, 1100 * (i + 1));
    // Median of ~1100 samples with sigma 10 mV: standard error ~0.4 mV.
    EXPECT_NEAR(a.plateaus[i].voltage_V, i % 2 == 0 ? 0.0 : 5.0, 0.003);
  }
  ASSERT_EQ(a.levels.size(), 1u);
  EXPECT_NEAR(a.levels[0].level_V, 5.0, 0.003);
  ASSERT_EQ(a.levels[0].segments.size(), 1u);
  ExpectSegment(a.levels[0].segments[0], 0, 0, 11000);
  // Automatic tolerance ~ 6 sigma = 60 mV (estimated from 11,000 differences).
  EXPECT_GT(a.tolerance_V, 0.045);
  EXPECT_LT(a.tolerance_V, 0.080);
}

TEST(Levels, SmallStepsInNoise) {
  // 0/0.2 V square wave with sigma 10 mV: the first pass caps the band at 5 % of the
  // range (~13 mV), the second re-estimates the noise inside the plateaus (6 sigma).
  Signal s = Sampled(6600, 10.0, [](size_t k) { return (k / 1100) % 2 == 1 ? 0.2 : 0.0; });
  AddNoise(&s, 0.010, 21);
  const LevelAnalysis a = DetectLevels(s.t_s, s.voltage_V);
  EXPECT_GT(a.tolerance_V, 0.045);
  EXPECT_LT(a.tolerance_V, 0.080);
  ASSERT_EQ(a.plateaus.size(), 6u);
  for (size_t i = 0; i < 6; ++i) {
    EXPECT_EQ(a.plateaus[i].begin, 1100 * i);
    EXPECT_EQ(a.plateaus[i].end, 1100 * (i + 1));
  }
  ASSERT_EQ(a.levels.size(), 1u);
  EXPECT_NEAR(a.levels[0].level_V, 0.2, 0.003);
}

TEST(Levels, NoisyStaircase) {
  Signal s = Blocks({0, 2, 4, 6, 8}, 1500);
  AddNoise(&s, 0.010, 7);
  const LevelAnalysis a = DetectLevels(s.t_s, s.voltage_V);
  ASSERT_EQ(a.levels.size(), 4u);
  for (size_t i = 0; i < 4; ++i)
    EXPECT_NEAR(a.levels[i].level_V, 2.0 * static_cast<double>(i + 1), 0.003);
  ExpectSegment(a.levels[2].segments[0], 4300, 4500, 6000);
}

TEST(Levels, LongExcursionsSplitPlateaus) {
  // A 3 s dip to 0 V inside a 5 V plateau is a real rest, not a glitch.
  const Signal s = Sampled(6000, 10.0, [](size_t k) {
    if (k < 1000) return 0.0;
    if (k >= 3000 && k < 3030) return 0.0;
    return 5.0;
  });
  const LevelAnalysis a = DetectLevels(s.t_s, s.voltage_V);
  ASSERT_EQ(a.plateaus.size(), 4u);
  EXPECT_EQ(a.plateaus[1].end, 3000u);
  EXPECT_EQ(a.plateaus[2].begin, 3000u);
  EXPECT_EQ(a.plateaus[2].end, 3030u);
  ASSERT_EQ(a.levels.size(), 1u);
  ASSERT_EQ(a.levels[0].segments.size(), 1u);
}

TEST(Levels, NonUniformTime) {
  // Jittered sampling (+-30 ms around 10 Hz) of a 0/5 V square wave defined in time.
  Gaussian random(3);
  Signal s;
  for (size_t k = 0; k < 11000; ++k) {
    const double t = static_cast<double>(k) / 10.0 + 0.06 * (random.Uniform() - 0.5);
    s.t_s.push_back(t);
    s.voltage_V.push_back(std::fmod(t, 220.0) >= 110.0 ? 5.0 : 0.0);
  }
  const LevelAnalysis a = DetectLevels(s.t_s, s.voltage_V);
  ASSERT_EQ(a.plateaus.size(), 10u);
  for (size_t i = 0; i < 10; ++i) {
    const double edge_s = 110.0 * static_cast<double>(i);
    EXPECT_GE(a.plateaus[i].t_start_s, edge_s);
    if (a.plateaus[i].begin > 0) {
      EXPECT_LT(s.t_s[a.plateaus[i].begin - 1], edge_s);
    }
  }
  ASSERT_EQ(a.levels.size(), 1u);
  ExpectSegment(a.levels[0].segments[0], 0, 0, 11000);

  // Staircase sampled at 10 Hz for the first two steps and 50 Hz after: the lead-in is
  // the preceding plateau's samples with t >= t[fit_begin] - 20 s.
  Signal stairs;
  double t = 0;
  while (t < 600.0) {
    stairs.t_s.push_back(t);
    stairs.voltage_V.push_back(std::floor(t / 150.0) * 2.0);
    t += t < 300.0 ? 0.1 : 0.02;
    t = std::round(t * 1000.0) / 1000.0;
  }
  const LevelAnalysis b = DetectLevels(stairs.t_s, stairs.voltage_V);
  ASSERT_EQ(b.levels.size(), 3u);
  for (const VoltageLevel& level : b.levels) {
    for (const LevelSegment& seg : level.segments) {
      if (seg.fit_begin == 0) continue;
      const double start_s = stairs.t_s[seg.fit_begin] - 20.0;
      EXPECT_GE(stairs.t_s[seg.begin], start_s - 1e-9);
      EXPECT_LT(stairs.t_s[seg.begin - 1], start_s);
      EXPECT_NEAR(stairs.voltage_V[seg.fit_begin - 1], stairs.voltage_V[seg.begin], 1e-12);
    }
  }
  EXPECT_NEAR(b.levels[2].level_V, 6.0, 1e-12);
}

TEST(Levels, ChirpIsNotAPlateauInput) {
  // 2.5 + 2.5 sin(2 pi (f0 t + (f1 - f0) t^2 / (2 T))), 0.01 -> 1 Hz over 600 s at 10 Hz.
  auto chirp = [](double sign) {
    return Sampled(6000, 10.0, [sign](size_t k) {
      const double t = static_cast<double>(k) / 10.0;
      const double phase = 2 * std::numbers::pi * (0.01 * t + 0.99 * t * t / 1200.0);
      return sign * (2.5 + 2.5 * std::sin(phase));
    });
  };
  for (double sign : {1.0, -1.0}) {
    const Signal s = chirp(sign);
    const LevelAnalysis a = DetectLevels(s.t_s, s.voltage_V);
    EXPECT_FALSE(a.plateau_input);
    ASSERT_EQ(a.levels.size(), 1u);
    ExpectSegment(a.levels[0].segments[0], 0, 0, 6000);
    // Independent truth: the mean |v| over the samples outside the rest band.
    double sum = 0;
    int count = 0;
    for (double v : s.voltage_V) {
      if (std::abs(v) <= a.rest_band_V) continue;
      sum += std::abs(v);
      ++count;
    }
    EXPECT_NEAR(a.levels[0].level_V, sign * sum / count, 1e-9);
    // The rest band cuts off the troughs, so the level lies a little above the 2.5 V mean.
    EXPECT_GT(sign * a.levels[0].level_V, 2.5);
    EXPECT_LT(sign * a.levels[0].level_V, 3.2);
    for (const Plateau& p : a.plateaus) EXPECT_LE(p.level, 0);
  }
}

TEST(Levels, ShortPulsesOnRestAreNotAPlateauInput) {
  // 1 s pulses of 4 V (shorter than min_hold_s) every 60 s on rest.
  const Signal s =
      Sampled(6000, 10.0, [](size_t k) { return k % 600 >= 300 && k % 600 < 310 ? 4.0 : 0.0; });
  const LevelAnalysis a = DetectLevels(s.t_s, s.voltage_V);
  EXPECT_FALSE(a.plateau_input);
  ASSERT_EQ(a.levels.size(), 1u);
  EXPECT_DOUBLE_EQ(a.levels[0].level_V, 4.0);
}

TEST(Levels, InputErrors) {
  const Signal good = SquareWave(5.0, 1);
  Signal s = good;
  s.t_s.resize(9);
  s.voltage_V.resize(9);
  EXPECT_EQ(DetectError(s), "too few samples (9): level detection needs at least 10");

  s = good;
  s.t_s[5] = NAN;
  EXPECT_EQ(DetectError(s), "time is not finite at sample 5");
  s = good;
  s.t_s[5] = s.t_s[4];
  EXPECT_EQ(DetectError(s), "time is not increasing at sample 5 (0.4 s after 0.4 s)");
  s = good;
  s.t_s[7] = 0.1;
  EXPECT_EQ(DetectError(s), "time is not increasing at sample 7 (0.1 s after 0.6 s)");
  s = good;
  s.voltage_V[3] = INFINITY;
  EXPECT_EQ(DetectError(s), "voltage is not finite at sample 3 (t = 0.3 s)");

  s = Sampled(100, 10.0, [](size_t) { return 5.0; });
  EXPECT_EQ(DetectError(s), "voltage is constant at 5 V: no excitation to identify from");

  // 5 V throughout except noise and spikes (one at the very first sample): no transition.
  s = Sampled(3000, 10.0, [](size_t) { return 5.0; });
  AddNoise(&s, 0.010, 11);
  s.voltage_V[0] = 7.0;
  s.voltage_V[1000] = 0.0;
  const std::string message = DetectError(s);
  const std::string prefix = "voltage level ";
  ASSERT_EQ(message.rfind(prefix, 0), 0u) << message;
  EXPECT_NEAR(std::stod(message.substr(prefix.size())), 5.0, 0.003) << message;
  EXPECT_NE(message.find(" V has no excitation: the recording holds it without a voltage "
                         "transition"),
            std::string::npos)
      << message;

  // 5 V held, then 8 V: the 5 V level is never entered, only left.
  s = Blocks({5, 8}, 1000);
  EXPECT_EQ(DetectError(s),
            "voltage level 5 V has no excitation: the recording holds it without a voltage "
            "transition");

  // Noise around 0 V only.
  s = Sampled(3000, 10.0, [](size_t) { return 0.0; });
  AddNoise(&s, 0.010, 12);
  EXPECT_EQ(DetectError(s).rfind("voltage stays within the rest band", 0), 0u);

  s = good;
  s.voltage_V.pop_back();
  EXPECT_THROW(DetectLevels(s.t_s, s.voltage_V), std::invalid_argument);
}

TEST(Levels, MergeAcrossRecordings) {
  const Signal low = SquareWave(2.0, 2);
  const Signal high = SquareWave(8.0, 3);
  std::vector<LevelAnalysis> analyses = {DetectLevels(low.t_s, low.voltage_V, {}, 0),
                                         DetectLevels(high.t_s, high.voltage_V, {}, 1)};
  const LevelAnalysis merged = MergeLevels(analyses, 0.0);
  ASSERT_EQ(merged.levels.size(), 2u);
  EXPECT_DOUBLE_EQ(merged.levels[0].level_V, 2.0);
  EXPECT_DOUBLE_EQ(merged.levels[1].level_V, 8.0);
  ASSERT_EQ(merged.levels[0].segments.size(), 1u);
  ASSERT_EQ(merged.levels[1].segments.size(), 1u);
  ExpectSegment(merged.levels[0].segments[0], 0, 0, 4400, 0);
  ExpectSegment(merged.levels[1].segments[0], 0, 0, 6600, 1);
  EXPECT_TRUE(merged.plateau_input);
  // Plateaus: 4 + 6, in recording order, level indices remapped.
  ASSERT_EQ(merged.plateaus.size(), 10u);
  EXPECT_EQ(merged.plateaus[1].recording, 0u);
  EXPECT_EQ(merged.plateaus[1].level, 0);
  EXPECT_EQ(merged.plateaus[5].recording, 1u);
  EXPECT_EQ(merged.plateaus[5].level, 1);
  EXPECT_EQ(merged.plateaus[4].level, -1);
  // Default merge tolerance: the largest of the inputs' (1e-3 of 8 V).
  EXPECT_DOUBLE_EQ(merged.tolerance_V, 8e-3);

  // Two recordings at nearly the same level merge with a fit-sample-weighted mean.
  const Signal a = SquareWave(5.0, 5);   // 11,000 samples
  const Signal b = SquareWave(5.02, 2);  // 4,400 samples
  const LevelAnalysis both = MergeLevels(
      {DetectLevels(a.t_s, a.voltage_V, {}, 0), DetectLevels(b.t_s, b.voltage_V, {}, 1)}, 0.05);
  ASSERT_EQ(both.levels.size(), 1u);
  EXPECT_NEAR(both.levels[0].level_V, (5.0 * 11000 + 5.02 * 4400) / 15400, 1e-12);
  ASSERT_EQ(both.levels[0].segments.size(), 2u);
  EXPECT_EQ(both.levels[0].segments[0].recording, 0u);
  EXPECT_EQ(both.levels[0].segments[1].recording, 1u);
  // With a tolerance below their difference they stay apart.
  EXPECT_EQ(
      MergeLevels(
          {DetectLevels(a.t_s, a.voltage_V, {}, 0), DetectLevels(b.t_s, b.voltage_V, {}, 1)}, 0.01)
          .levels.size(),
      2u);

  EXPECT_TRUE(MergeLevels({}, 0.0).levels.empty());
  EXPECT_THROW(MergeLevels(analyses, -1.0), std::invalid_argument);
}

TEST(Levels, MillionSamples) {
  // 1,000,000 samples at 10 Hz (27.8 h) of a noisy 0/5 V square wave; timing is printed,
  // not asserted.
  Signal s = Sampled(1000000, 10.0, [](size_t k) { return (k / 1100) % 2 == 1 ? 5.0 : 0.0; });
  AddNoise(&s, 0.010, 5);
  const auto start = std::chrono::steady_clock::now();
  const LevelAnalysis a = DetectLevels(s.t_s, s.voltage_V);
  const auto elapsed = std::chrono::steady_clock::now() - start;
  std::cout << "DetectLevels on 1,000,000 samples: "
            << std::chrono::duration<double, std::milli>(elapsed).count() << " ms\n";
  ASSERT_EQ(a.levels.size(), 1u);
  EXPECT_EQ(a.plateaus.size(), (1000000 + 1099) / 1100);
  ASSERT_EQ(a.levels[0].segments.size(), 1u);
}

TEST(Levels, Deterministic) {
  Signal s = Blocks({0, 2, 0, -4, 6, 0}, 1000);
  AddNoise(&s, 0.02, 9);
  const LevelAnalysis a = DetectLevels(s.t_s, s.voltage_V);
  const LevelAnalysis b = DetectLevels(s.t_s, s.voltage_V);
  ASSERT_EQ(a.plateaus.size(), b.plateaus.size());
  for (size_t i = 0; i < a.plateaus.size(); ++i) {
    EXPECT_EQ(a.plateaus[i].begin, b.plateaus[i].begin);
    EXPECT_EQ(a.plateaus[i].voltage_V, b.plateaus[i].voltage_V);
  }
  ASSERT_EQ(a.levels.size(), 3u);
  EXPECT_EQ(a.levels[0].level_V, b.levels[0].level_V);
}

}  // namespace
}  // namespace flexid::model
