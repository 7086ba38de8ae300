#pragma once
// For tests on an in-process bus (memq://).

#include <chrono>
#include <future>
#include <string>

#include <gtest/gtest.h>
#include <lcm/lcm-cpp.hpp>

namespace stitch::testing {

// memq:// delivers in order: once a marker published now is handled, so is everything published
// on `lcm` before it (the services' final states included), however far behind the dispatcher
// runs (a sanitizer build on a loaded machine). Fails the test after 2 minutes.
inline void WaitUntilDispatched(lcm::LCM* lcm) {
  std::promise<void> handled;
  auto* subscription = lcm->subscribeFunction(
      "TEST_DISPATCHED", +[](const lcm::ReceiveBuffer*, const std::string&, std::promise<void>* p) { p->set_value(); },
      &handled);
  const uint8_t marker = 0;
  lcm->publish("TEST_DISPATCHED", &marker, 1);
  EXPECT_EQ(handled.get_future().wait_for(std::chrono::seconds(120)), std::future_status::ready)
      << "the bus did not deliver what was published within 2 minutes";
  lcm->unsubscribe(subscription);
}

}  // namespace stitch::testing
