"""Campaign files are validated before anything runs (issue 26, item 3): rotor indices, tasks, sizes.

Each mistake is one :class:`~omnirotor.errors.InputError` (the CLI's one line and exit status 2).
"""

from __future__ import annotations

import pytest

from omnirotor.errors import InputError
from omnirotor.experiments.campaigns.spec import campaign_from_mapping
from omnirotor.limits import MAX_CAMPAIGN_RUNS


def _file(**vary) -> dict:
    return {"task": "hover", "runs": 2, "vary": vary}


def test_a_failed_rotor_the_vehicle_does_not_have_is_refused():
    with pytest.raises(InputError, match=r"rotor 99 does not exist.*rotors 1\.\.8 \(0 = none\)"):
        campaign_from_mapping(_file(failed_rotor={"dist": "constant", "value": 99}))
    with pytest.raises(InputError, match="rotor 9 does not exist"):
        campaign_from_mapping(_file(failed_rotor={"dist": "choice", "values": [0, 3, 9]}))
    with pytest.raises(InputError, match="outside"):
        campaign_from_mapping(_file(failed_rotor={"dist": "constant", "value": -1}))
    spec = campaign_from_mapping(_file(failed_rotor={"dist": "choice", "values": [0, 1, 8]}))  # the edges are fine
    assert dict(spec.vary)["failed_rotor"].support() == (0, 1, 8)


def test_unknown_tasks_parameters_and_sizes_are_refused():
    with pytest.raises(InputError, match="task"):
        campaign_from_mapping({"task": "juggling", "runs": 2})
    with pytest.raises(InputError, match="unknown parameter"):
        campaign_from_mapping(_file(rotor_count={"dist": "constant", "value": 3}))
    with pytest.raises(InputError, match=rf"runs must lie in 1\.\.{MAX_CAMPAIGN_RUNS}"):
        campaign_from_mapping({"task": "hover", "runs": MAX_CAMPAIGN_RUNS + 1})
    with pytest.raises(InputError, match="runs must lie"):
        campaign_from_mapping({"task": "hover", "runs": 0})
