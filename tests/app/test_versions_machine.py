"""The versions of the calibration in use through arbitrary interleavings of the engine's life (arming, programs,
bumps, bad samples, carry-over) with policies, consumers, approvals and restarts (bench.monitor_campaign's
VersionsMachine): no version, approval or acknowledgement lost; the file, the history and the status agree."""

import logging
import os

from hypothesis import HealthCheck, Phase, settings

from bench.monitor_campaign import engine_machine

VersionsMachine = engine_machine(versions=True)

TestVersionsMachine = VersionsMachine.TestCase
# No explain phase: its line tracing, on from the first failure found, made shrinking 30x slower on 3.12, and
# pytest-timeout ended it with the failure unreported.
TestVersionsMachine.settings = settings(max_examples=int(os.environ.get("HANDEYE_CAMPAIGN_EXAMPLES", "20")),
                                        stateful_step_count=25, deadline=None, derandomize=True, database=None,
                                        phases=(Phase.explicit, Phase.generate, Phase.shrink),
                                        suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
# A flaky consumer is out of reach at every other call: one warning each, thousands per run.
logging.getLogger("handeye.app.consumers").setLevel(logging.ERROR)
