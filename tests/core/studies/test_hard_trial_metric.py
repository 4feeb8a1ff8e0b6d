"""hard_trial's GC form option (--metric)."""

import pytest

from core.studies.tracking import hard_trial


def test_an_unknown_metric_form_is_rejected_before_any_work():
    with pytest.raises(ValueError, match="metric"):
        hard_trial.run(metric="vectors")
    assert hard_trial.METRIC_FORMS == ("magnitudes", "components")
