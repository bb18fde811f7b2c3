// Writes the binary seed inputs of the fuzz targets that take bus messages:
//   DIR/lcm_message/<type>: byte 0 selects the type (fuzz_lcm_message.cc), then one
//     encoded message;
//   DIR/trial_import/log-*.lcmlog: small lcm-logger logs of actuator S1.
// Usage: fuzz_make_seeds tests/fuzz/corpus (after a message type changes).
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <flexid/alert_t.hpp>
#include <flexid/deflection_sample_t.hpp>
#include <flexid/ownership_t.hpp>
#include <flexid/prediction_t.hpp>
#include <flexid/rpc_reply_t.hpp>
#include <flexid/rpc_request_t.hpp>
#include <flexid/status_t.hpp>
#include <flexid/trial_control2_t.hpp>
#include <flexid/trial_control_t.hpp>
#include <flexid/voltage_command_t.hpp>
#include <flexid/voltage_sample_t.hpp>
#include <fstream>
#include <lcm/lcm-cpp.hpp>
#include <string>
#include <vector>

namespace fs = std::filesystem;

namespace {

template <typename Message>
std::vector<uint8_t> Encode(const Message& message) {
  std::vector<uint8_t> bytes(static_cast<size_t>(message.getEncodedSize()));
  message.encode(bytes.data(), 0, static_cast<int>(bytes.size()));
  return bytes;
}

template <typename Message>
void WriteSeed(const fs::path& dir, uint8_t selector, const std::string& name,
               const Message& message) {
  std::vector<uint8_t> bytes = Encode(message);
  bytes.insert(bytes.begin(), selector);
  std::ofstream(dir / name, std::ios::binary)
      .write(reinterpret_cast<const char*>(bytes.data()),
             static_cast<std::streamsize>(bytes.size()));
}

flexid::voltage_sample_t Voltage(int64_t utime, double v) {
  flexid::voltage_sample_t m{};
  m.utime = utime;
  m.actuator_id = "S1";
  m.voltage_V = v;
  return m;
}

flexid::deflection_sample_t Deflection(int64_t utime, double d) {
  flexid::deflection_sample_t m{};
  m.utime = utime;
  m.actuator_id = "S1";
  m.deflection_mm = d;
  return m;
}

flexid::trial_control_t Control(int64_t utime, int8_t action) {
  flexid::trial_control_t m{};
  m.utime = utime;
  m.actuator_id = "S1";
  m.action = action;
  m.protocol = "step:level=2,duration=1";
  return m;
}

template <typename Message>
void Log(lcm::LogFile* log, int64_t* eventnum, const std::string& channel, const Message& m) {
  std::vector<uint8_t> bytes = Encode(m);
  lcm::LogEvent event;
  event.eventnum = (*eventnum)++;
  event.timestamp = m.utime;
  event.channel = channel;
  event.datalen = static_cast<int32_t>(bytes.size());
  event.data = bytes.data();
  log->writeEvent(&event);
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: fuzz_make_seeds CORPUS_DIR\n");
    return 2;
  }
  const fs::path root = argv[1];
  const fs::path messages = root / "lcm_message";
  const fs::path imports = root / "trial_import";
  fs::create_directories(messages);
  fs::create_directories(imports);

  const int64_t t0 = 1700000000000000;
  WriteSeed(messages, 0x80, "voltage_sample_t", Voltage(t0, 2.0));
  WriteSeed(messages, 0x81, "deflection_sample_t", Deflection(t0, 0.5));
  flexid::prediction_t p{};
  p.utime = t0;
  p.actuator_id = "S1";
  p.voltage_V = 2;
  p.measured_mm = 0.5;
  p.predicted_mm = 0.48;
  p.residual_mm = 0.02;
  p.model_version = 3;
  p.trial_id = 4;
  p.memberships = {0.25, 0.75};
  p.num_memberships = 2;
  WriteSeed(messages, 0x82, "prediction_t", p);
  flexid::alert_t a{};
  a.utime = t0;
  a.actuator_id = "S1";
  a.kind = "back_relaxation";
  a.severity = 1;
  a.start_utime = t0 - 60000000;
  a.end_utime = t0;
  a.magnitude_mm = 1.5;
  a.threshold_mm = 0.2;
  a.text = "trial 4: back-relaxation";
  WriteSeed(messages, 0x83, "alert_t", a);
  WriteSeed(messages, 0x84, "trial_control_t", Control(t0, flexid::trial_control_t::kStart));
  flexid::trial_control2_t signed_control{};
  signed_control.utime = t0;
  signed_control.actuator_id = "S1";
  signed_control.action = flexid::trial_control2_t::kStart;
  signed_control.protocol = "step:level=2,duration=1";
  signed_control.sent_utime = t0;
  signed_control.nonce = "0123456789abcdef";
  signed_control.auth = std::string(64, 'a');
  WriteSeed(messages, 0x88, "trial_control2_t", signed_control);
  flexid::voltage_command_t command{};
  command.utime = t0 + 100000;
  command.actuator_id = "S1";
  command.voltage_V = 2.5;
  command.sequence = 1;
  command.controller_id = "control-1";
  command.mode = flexid::voltage_command_t::kTrack;
  command.reference_mm = 10.0;
  command.reference_utime = t0;
  command.sent_utime = t0;
  command.nonce = "0123456789abcdef";
  command.auth = std::string(64, 'b');
  WriteSeed(messages, 0x89, "voltage_command_t", command);
  flexid::ownership_t ownership{};
  ownership.utime = t0;
  ownership.daemon_id = "FLEXID";
  ownership.instance_id = "0123456789abcdef";
  ownership.num_claims = 2;
  ownership.actuator_ids = {"S1", "S2"};
  ownership.claims = {flexid::ownership_t::kConfigured, flexid::ownership_t::kAdopted};
  ownership.first_seen_utime = {0, t0 - 1000000};
  ownership.num_peers = 1;
  ownership.peer_ids = {"RIG2"};
  ownership.peer_heard_utime = {t0 - 500000};
  WriteSeed(messages, 0x8A, "ownership_t", ownership);
  flexid::rpc_request_t q{};
  q.utime = t0;
  q.request_id = "r1";
  q.client_id = "cli-1";
  q.method = "trials";
  q.args_json = R"({"actuator": "S1", "limit": 10})";
  WriteSeed(messages, 0x85, "rpc_request_t", q);
  flexid::rpc_reply_t r{};
  r.utime = t0;
  r.request_id = "r1";
  r.daemon_id = "flexidd";
  r.status = flexid::rpc_reply_t::kOk;
  r.result_json = R"({"trials": []})";
  r.error = "";
  WriteSeed(messages, 0x86, "rpc_reply_t", r);
  flexid::status_t s{};
  s.utime = t0;
  s.daemon_id = "flexidd";
  s.version = "0.1.0";
  WriteSeed(messages, 0x87, "status_t", s);

  {  // A trial between two trial controls, with a stray deflection of S2 and a bad event.
    lcm::LogFile log((imports / "log-trial.lcmlog").string(), "w");
    int64_t n = 0;
    Log(&log, &n, "FLEXID/TRIAL", Control(t0, flexid::trial_control_t::kStart));
    for (int k = 0; k < 6; ++k) {
      if (k % 3 == 0) Log(&log, &n, "FLEXID/S1/VOLTAGE", Voltage(t0 + k * 100000, k % 2 ? 0 : 2));
      Log(&log, &n, "FLEXID/S1/DEFLECTION", Deflection(t0 + k * 100000 + 50, 0.1 * k));
    }
    flexid::deflection_sample_t other = Deflection(t0 + 700000, 1);
    other.actuator_id = "S2";
    Log(&log, &n, "FLEXID/S2/DEFLECTION", other);
    Log(&log, &n, "FLEXID/TRIAL", Control(t0 + 800000, flexid::trial_control_t::kStop));
  }
  {  // No trial controls: the whole log is one trial.
    lcm::LogFile log((imports / "log-plain.lcmlog").string(), "w");
    int64_t n = 0;
    Log(&log, &n, "FLEXID/S1/VOLTAGE", Voltage(t0, 4));
    for (int k = 0; k < 4; ++k)
      Log(&log, &n, "FLEXID/S1/DEFLECTION", Deflection(t0 + k * 200000, 0.2 * k));
  }
  return 0;
}
