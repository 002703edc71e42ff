"""The monitoring engine through arbitrary interleavings of arming, programs, moves and bad samples (a bounded run
of bench.monitor_campaign's state machine; ``python -m bench --fuzz --only monitor`` runs a long one)."""

import os

from hypothesis import HealthCheck, Phase, settings

from bench.monitor_campaign import engine_machine

EngineMachine = engine_machine()

TestEngineMachine = EngineMachine.TestCase
# No explain phase: its line tracing, on from the first failure found, made shrinking 30x slower on 3.12, and
# pytest-timeout ended it with the failure unreported.
TestEngineMachine.settings = settings(max_examples=int(os.environ.get("HANDEYE_CAMPAIGN_EXAMPLES", "25")),
                                      stateful_step_count=25, deadline=None, derandomize=True, database=None,
                                      phases=(Phase.explicit, Phase.generate, Phase.shrink),
                                      suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
