"""Plain numbers for reports and command output (`diagnose.plain`)."""

import pytest

from diagnose.plain import duration, number, percent_change


@pytest.mark.parametrize("seconds,text", [(0.04, "0.04 s"), (2.5, "2.5 s"), (45, "45 s"), (600, "10 min"),
                                          (3480, "58 min"), (36000, "10 h"), (86604, "24.1 h"),
                                          (1.9797e6, "22.9 days"), (-90, "-90 s"), (None, "-"),
                                          (float("nan"), "-")])
def test_durations_are_in_the_unit_an_engineer_says(seconds, text):
    assert duration(seconds) == text


@pytest.mark.parametrize("value,text", [(3480.0, "3480"), (1.9797e6, "1979700"), (0.0123456, "0.0123"),
                                        (9.04, "9.04"), (-2.3289, "-2.33"), (3.12e-5, "0.0000312"),
                                        (1e-12, "0"), (True, "-")])
def test_numbers_never_use_an_exponent(value, text):
    assert number(value) == text


def test_a_change_is_signed_by_its_direction():
    assert percent_change(-0.05) == "-5 %" and percent_change(0.12) == "+12 %" and percent_change(None) == "-"
    # a change that rounds to nothing has no sign (never "-0 %")
    assert percent_change(-0.003) == percent_change(0.004) == percent_change(0.0) == "0 %"
    # many times worse reads as such, not as "+26708 %"
    assert percent_change(9.99) == "+999 %" and percent_change(267.08) == percent_change(9.996) == "> +999 %"


@pytest.mark.parametrize("fraction,text", [(0.97, "97 %"), (0.5, "50 %"), (0.9999, "> 99 %"), (1.0, "> 99 %"),
                                           (0.001, "< 1 %"), (0.0, "0 %"), (None, "-")])
def test_a_probability_never_reads_as_a_certainty_it_is_not(fraction, text):
    from diagnose.plain import percent

    assert percent(fraction) == text
