// flexidd's configuration: the shipped example loads, bad files are named precisely.
#include "daemon/config.h"

#include <gtest/gtest.h>

#include <fstream>

#include "scratch_dir.h"

namespace flexid::daemon {
namespace {

std::string ErrorOf(const std::string& path) {
  try {
    Validate(LoadConfigFile(path));
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "no error";
}

TEST(Config, TheExampleFileLoadsAndValidates) {
  const Config c = LoadConfigFile(std::string(FLEXID_SOURCE_DIR) + "/deploy/flexidd.toml");
  Validate(c);
  EXPECT_EQ(c.daemon_id, "lab-rig-1");
  EXPECT_EQ(c.lcm_url, "udpm://239.255.76.67:7667?ttl=0");
  EXPECT_EQ(c.commit_interval_ms, 100);
  ASSERT_EQ(c.actuators.size(), 1u);
  EXPECT_EQ(c.actuators[0].id, "S1");
  EXPECT_EQ(c.actuators[0].thickness_mm, 2.0);
  EXPECT_EQ(c.identification.poles, 4);
  EXPECT_EQ(c.identification.max_diagnosis_samples, 200000);
  EXPECT_EQ(c.alerts.false_alarms_per_hour, 0.1);
  EXPECT_EQ(c.alerts.sigma_floor_mm, 0.005);
  EXPECT_FALSE(Describe(c).empty());
}

TEST(Config, DefaultsAreValid) { Validate(Config{}); }

TEST(Config, BadFilesAreNamedWithTheProblem) {
  testing::ScratchDir dir;
  auto write = [&](const std::string& name, const std::string& text) {
    std::ofstream(dir.File(name)) << text;
    return dir.File(name);
  };
  EXPECT_NE(ErrorOf(write("typo.toml", "databse = \"x.db\"\n")).find("unknown setting \"databse\""),
            std::string::npos);
  EXPECT_NE(ErrorOf(write("type.toml", "commit_interval_ms = \"fast\"\n"))
                .find("commit_interval_ms: expected an integer"),
            std::string::npos);
  EXPECT_NE(ErrorOf(write("range.toml", "commit_interval_ms = 500\n")).find("<= 200 ms"),
            std::string::npos);
  const std::string syntax = ErrorOf(write("syntax.toml", "a = [1, 2\n"));
  EXPECT_NE(syntax.find("syntax.toml:"), std::string::npos) << syntax;
  EXPECT_NE(ErrorOf(write("dup.toml", "[[actuators]]\nid = \"S1\"\n[[actuators]]\nid = \"S1\"\n"))
                .find("appears twice"),
            std::string::npos);
  // Actuator ids name LCM channels: the bus's one rule (bus/ids.h), no '.'.
  const std::string dotted = ErrorOf(write("dot.toml", "[[actuators]]\nid = \"S.1\"\n"));
  EXPECT_NE(dotted.find("id \"S.1\": expected 1 to 64 of A-Z a-z 0-9 _ -"), std::string::npos)
      << dotted;
  // The channel prefix: the clients' --channel-prefix rule (bus/channels.h), '.' allowed.
  EXPECT_EQ(ErrorOf(write("prefix.toml", "channel_prefix = \"lab.2\"\n")), "no error");
  const std::string slashed = ErrorOf(write("slash.toml", "channel_prefix = \"lab/2\"\n"));
  EXPECT_NE(slashed.find("channel_prefix: expected 1 to 64 of A-Z a-z 0-9 _ . - (got \"lab/2\")"),
            std::string::npos)
      << slashed;
  EXPECT_NE(ErrorOf(write("geom.toml", "[[actuators]]\nid = \"S1\"\nlength_mm = -4\n"))
                .find("dimensions"),
            std::string::npos);
  EXPECT_NE(ErrorOf(write("orders.toml", "[identification]\nzeros = 4\npoles = 4\n"))
                .find("zeros < poles"),
            std::string::npos);
  EXPECT_NE(ErrorOf(write("diagnosis.toml", "[identification]\nmax_diagnosis_samples = 10\n"))
                .find("identification.max_diagnosis_samples: must be >= 200"),
            std::string::npos);
  // The floor under the monitor's sigma: a number, finite and > 0.
  EXPECT_EQ(ErrorOf(write("floor.toml", "[alerts]\nsigma_floor_mm = 0.001\n")), "no error");
  for (const char* bad : {"0", "-0.01", "nan", "inf"})
    EXPECT_EQ(ErrorOf(write("floor.toml", std::string("[alerts]\nsigma_floor_mm = ") + bad + "\n")),
              "alerts: sigma_floor_mm must be finite and > 0")
        << bad;
  EXPECT_NE(ErrorOf(write("floor.toml", "[alerts]\nsigma_floor_mm = \"fine\"\n"))
                .find("alerts.sigma_floor_mm: expected a number"),
            std::string::npos);
  EXPECT_NE(ErrorOf(dir.File("missing.toml")).find("missing.toml"), std::string::npos);
}

}  // namespace
}  // namespace flexid::daemon
