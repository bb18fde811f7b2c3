// Voltage levels of a recording: where the applied voltage holds still (plateaus), which
// distinct voltages it holds (levels), and which stretches of the recording show each
// level's behaviour (segments). Identification fits one local transfer function per
// level on that level's segments and blends them in a Takagi-Sugeno model scheduled on
// |voltage| (ts_fuzzy.h).
//
// Notation: v_k = voltage_V[k], t_k = t_s[k], k = 0..N-1; tau = the plateau tolerance (V);
// G = LevelDetectionOptions::max_glitch_samples.
//
// Algorithm (O(N), apart from sorting the P plateau voltages, O(P log P)):
//  1. Tolerance, two passes. sigma_v = Q_0.8(|dv_k - median(dv)|) / (1.2816 sqrt 2), with
//     dv_k = v_{k+1} - v_k: a robust noise scale from first differences, which are noise
//     (variance 2 sigma_v^2) except at the few transitions. It is the 80th percentile of the
//     absolute deviations rather than the median (MAD) because a quantising DAQ can make
//     more than half of the differences exactly zero while the noise is still one or two
//     LSB; it breaks down only if more than 20 % of the differences are transitions.
//     First pass, over all samples:
//       tau_1 = max(1e-3 R, min(6 sigma_v, 0.05 R)),   R = max v - min v,
//     where the cap 0.05 R keeps the band narrow on non-plateau inputs (a chirp's
//     differences are signal, not noise), except when the recording is noise around a
//     constant (sigma_v >= 0.5 s_v, s_v = Q_0.8(|v - median v|) / 1.2816 the robust spread
//     of the voltage itself): then tau_1 = max(1e-3 R, 6 sigma_v), uncapped.
//     Second pass, if at least half the samples lie on the plateaus found with tau_1:
//     sigma_v again, from the differences inside those plateaus only (the transitions and
//     the signal are gone), tau = max(1e-3 R, 6 sigma_v), and the plateaus are found
//     again with it. 6 sigma keeps Gaussian noise inside the band (rare exceedances are
//     glitches, step 2); the floor 1e-3 R covers noise-free and coarsely quantised data.
//     Statistics over more than 2^17 values use a deterministic stride through them.
//  2. Plateaus: a greedy scan. A run starts at sample i and takes every next sample within
//     tau of the running mean of the run's accepted samples. A sample outside the band ends
//     the run unless the voltage comes back within tau in at most G samples: such an
//     excursion is a glitch (a spike), kept inside the run but left out of its mean. A run
//     is a plateau if t_last - t_first >= min_hold_s; otherwise the scan restarts at the
//     sample that ended it. The plateau voltage is the mean of its in-band samples (a
//     trimmed mean: glitches are left out).
//  3. Rest band b: |plateau voltage| <= b is rest (0 V). Automatic:
//       b = max(tau, 0.02 V_ref),  V_ref = max |plateau voltage| (99th percentile of |v|
//     when there is no plateau), so that a small DAQ offset at 0 V still reads as rest.
//  4. Levels: non-rest plateau voltages sorted ascending and clustered (a new cluster
//     starts where a voltage exceeds the running duration-weighted mean of the current
//     cluster by more than tau); level_V is the duration-weighted mean, so -5 V and +5 V
//     are different levels.
//  5. Segments: a rest plateau takes the level of the preceding non-rest plateau (the
//     relaxation after an excitation is that level's behaviour), or of the following one
//     when none precedes. Consecutive plateaus of one level form one segment. The fit part
//     of a segment runs from the end of the previous segment's last plateau (from sample 0
//     for the first segment) to the end of its own last plateau (to N for the last
//     segment), so transitions belong to the segment they lead into and the segments'
//     fit parts partition [0, N). The lead-in adds the samples of the preceding plateau
//     with t_k >= t[fit_begin] - lead_in_s.
//  6. Non-plateau input: fewer than half the samples on plateaus, or no non-rest plateau
//     at all. Then plateau_input = false and there is one level at the mean |v| of the
//     non-rest samples (|v| > b), signed by the dominant polarity (the sign of the sum of
//     their voltages), with one segment [0, N); the plateaus found are still reported,
//     the non-rest ones with level 0.
//  7. Excitation: a segment shows a transition if the plateaus it touches (including the
//     lead-in's, or the sample just before it when there is no lead-in) differ by more
//     than tau, or if it holds more than G consecutive samples that are on no plateau.
//     Every level needs at least one segment with a transition.
#pragma once

#include <cstddef>
#include <span>
#include <string>
#include <vector>

namespace flexid::model {

struct LevelDetectionOptions {
  double min_hold_s = 2.0;     // a plateau must last at least this long (t_last - t_first)
  double tolerance_V = 0.0;    // half-width of the plateau band; 0 = automatic (header, step 1)
  double rest_band_V = 0.0;    // |v| at or below this is rest (0 V); 0 = automatic (step 3)
  double lead_in_s = 20.0;     // how much of the preceding plateau to include before a segment
  int max_glitch_samples = 5;  // an excursion of at most this many samples is a glitch

  // True if every field is finite and in range (min_hold_s > 0, the others >= 0);
  // otherwise false with a one-line reason in *error (if error is not null).
  bool IsValid(std::string* error) const;
};

struct Plateau {
  size_t begin = 0, end = 0;          // samples [begin, end), glitches included
  double t_start_s = 0, t_end_s = 0;  // t_s[begin] and t_s[end - 1]
  double voltage_V = 0;               // mean of the in-band samples (glitches left out)
  int level = -1;                     // index into LevelAnalysis::levels, -1 for rest
  size_t recording = 0;               // index of the recording the samples belong to
};

struct LevelSegment {
  size_t recording = 0;  // index of the recording (for multi-recording analysis)
  size_t begin = 0;      // first sample of the segment, including the lead-in
  size_t fit_begin = 0;  // first sample after the lead-in (begin <= fit_begin < end)
  size_t end = 0;        // one past the last sample
};

struct VoltageLevel {
  double level_V = 0;                  // signed level voltage
  std::vector<LevelSegment> segments;  // in time order (by recording, then begin)
};

struct LevelAnalysis {
  std::vector<Plateau> plateaus;     // in time order (by recording, then begin)
  std::vector<VoltageLevel> levels;  // sorted ascending by level_V
  bool plateau_input = true;         // false: non-plateau input (header, step 6)
  double tolerance_V = 0;            // effective plateau tolerance (automatic or given)
  double rest_band_V = 0;            // effective rest band (automatic or given)
};

// Finds the plateaus, levels and segments of one recording (header). `recording` is
// copied into every plateau and segment. Throws std::invalid_argument if the spans differ
// in length or the options are invalid, and InputError (one line) for: fewer than 10
// samples; non-finite or non-increasing time; non-finite voltage; a constant voltage; a
// voltage that never leaves the rest band; a level without excitation.
LevelAnalysis DetectLevels(std::span<const double> t_s, std::span<const double> voltage_V,
                           const LevelDetectionOptions& options = {}, size_t recording = 0);

// Merges the analyses of several recordings: levels whose voltages are within tolerance_V
// of a cluster's running mean merge (clustered ascending as in DetectLevels), level_V
// becomes the mean weighted by each level's fit samples (sum of end - fit_begin), and the
// segments keep their recording index. tolerance_V = 0 uses the largest effective
// tolerance of the inputs. Plateaus are concatenated with their level indices remapped;
// plateau_input is true only if it is true for every input; the result's tolerance_V is
// the merge tolerance used and its rest_band_V the largest of the inputs'. No input gives
// an empty analysis. Throws std::invalid_argument if tolerance_V is negative or not finite.
LevelAnalysis MergeLevels(const std::vector<LevelAnalysis>& per_recording, double tolerance_V);

}  // namespace flexid::model
