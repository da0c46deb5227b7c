"""A kind of vehicle for the batch tests (a vehicle file names it with ``assembly =
"tests.batch_failing_kind"``): it loads any table and fails every offline run with an error whose text
holds line breaks, a tab, quotes and non-ASCII characters, to check that such a text comes back from the
journal unchanged."""
from __future__ import annotations

from rtsim.vehicle.registry import VehicleKind

MESSAGE = "line one\nline two\twith a tab, 'single' and \"double\" quotes, a comma,\r\nünïcödé ✓ 漢字 and a last line"


class FailingKind(VehicleKind):
    name = "failing_for_tests"

    def load(self, data, path):
        return dict(data), path.parent

    def build(self, opened):
        return None

    def random_elements(self, opened, sc):
        return []

    def run_offline(self, opened, sc, progress=None, seed=0):
        raise RuntimeError(MESSAGE)


KIND = FailingKind()
