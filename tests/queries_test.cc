// storage/queries.h: the read-only RPC methods answered from a database file, as flexidd
// and `flexid --db` both answer them: shapes, bounds, and errors that name the problem.
#include "storage/queries.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "scratch_dir.h"
#include "storage/database.h"

namespace flexid {
namespace {

using nlohmann::json;
using storage::QueryError;

class Queries : public ::testing::Test {
 protected:
  void SetUp() override {
    db_.StartTrial("S1", "square:level=5", 1'000'000);
    trial_ = db_.Trials().front().id;
    std::vector<storage::Sample> samples;
    for (int k = 0; k < 30; ++k) samples.push_back({1'000'000 + k * 10'000, 5.0, 0.1 * k});
    db_.AppendSamples(trial_, samples);
    db_.EndTrial(trial_, 1'290'000, storage::TrialState::kComplete);
    storage::ModelRecord model;
    model.actuator_id = "S1";
    model.model_json = R"({"format": "flexid.model/1", "kind": "tf", "num": [1], "den": [1, 1]})";
    model.fit_json = "{}";
    model.active = true;
    db_.StoreModel(model);
    storage::AlertRecord alert;
    alert.actuator_id = "S1";
    alert.kind = "residual";
    alert.utime = 1'100'000;
    alert.text = "residual above threshold";
    db_.StoreAlert(alert);
  }
  json Answer(const std::string& method, const json& args) {
    return storage::AnswerQuery(db_, method, args);
  }
  QueryError::Kind ErrorOf(const std::string& method, const json& args, std::string* text) {
    try {
      Answer(method, args);
    } catch (const QueryError& e) {
      *text = e.what();
      return e.kind;
    }
    ADD_FAILURE() << method << " " << args.dump() << " was answered";
    return QueryError::Kind::kBadArgument;
  }

  testing::ScratchDir scratch_;
  storage::Database db_ = storage::Database::Open(scratch_.File("flexid.db"));
  int64_t trial_ = 0;
};

TEST_F(Queries, AnswerTheMethodsInFlexiddsShapes) {
  const json trials = Answer("trials", {{"actuator", "S1"}});
  ASSERT_EQ(trials.size(), 1u);
  EXPECT_EQ(trials[0]["id"], trial_);
  EXPECT_EQ(trials[0]["samples"], 30);
  const json page = Answer("trial_samples", {{"trial", trial_}, {"offset", 10}, {"limit", 5}});
  EXPECT_EQ(page["utime"].size(), 5u) << page.dump();
  EXPECT_EQ(page["utime"][0], 1'100'000);
  EXPECT_EQ(page["total"], 30);
  const json models = Answer("models", {{"actuator", "S1"}});
  ASSERT_EQ(models.size(), 1u);
  const json model = Answer("model", {{"actuator", "S1"}});
  EXPECT_EQ(model["version"], 1);
  EXPECT_EQ(model["model"]["kind"], "tf");
  EXPECT_EQ(Answer("alerts", json::object()).size(), 1u);
  EXPECT_EQ(Answer("alerts", {{"since_utime", 2'000'000}}).size(), 0u);
  EXPECT_TRUE(storage::IsStoredQuery("trials"));
  EXPECT_FALSE(storage::IsStoredQuery("status"));
  EXPECT_THROW(Answer("identify", json::object()), std::invalid_argument);
}

TEST_F(Queries, BadArgumentsAndMissingRecordsAreNamed) {
  std::string text;
  EXPECT_EQ(ErrorOf("trials", {{"limit", 0}}, &text), QueryError::Kind::kBadArgument);
  EXPECT_NE(text.find("\"limit\" must be in [1, 10000]"), std::string::npos) << text;
  EXPECT_EQ(ErrorOf("trials", {{"actuator", "S9"}}, &text), QueryError::Kind::kNotFound);
  EXPECT_NE(text.find("unknown actuator \"S9\""), std::string::npos) << text;
  EXPECT_EQ(ErrorOf("trial_samples", json::object(), &text), QueryError::Kind::kBadArgument);
  EXPECT_NE(text.find("missing argument \"trial\""), std::string::npos) << text;
  EXPECT_EQ(ErrorOf("trial_samples", {{"trial", trial_ + 7}}, &text), QueryError::Kind::kNotFound);
  EXPECT_EQ(ErrorOf("model", {{"actuator", "S1"}, {"version", 9}}, &text),
            QueryError::Kind::kNotFound);
  EXPECT_NE(text.find("no model version 9 of S1"), std::string::npos) << text;
  EXPECT_EQ(ErrorOf("models", json::object(), &text), QueryError::Kind::kBadArgument);
  // Above INT64_MAX a JSON integer parses as unsigned: refused, never wrapped.
  EXPECT_EQ(ErrorOf("alerts", json::parse(R"({"since_utime": 18446744073709551615})"), &text),
            QueryError::Kind::kBadArgument);
  EXPECT_EQ(ErrorOf("trials", {{"limit", "ten"}}, &text), QueryError::Kind::kBadArgument);
  EXPECT_NE(text.find("must be an integer"), std::string::npos) << text;
  EXPECT_EQ(ErrorOf("trials", json::array(), &text), QueryError::Kind::kBadArgument);
}

}  // namespace
}  // namespace flexid
