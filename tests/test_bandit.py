"""ULTHO bandit: hand-computed sequences, properties, persistence and every error."""

import json
import math
import re

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ultho_bandit import ULTHO, clusters_of_interest, format_value, parse_clusters

# ----------------------------------------------------------------------------------------------------------
# Hand-computed sequences. The bounds in the comments were worked out with a calculator, not with the module.
# ----------------------------------------------------------------------------------------------------------


def test_two_clusters_sequence_with_window_eviction():
    bandit = ULTHO({"a": [1, 2], "b": [10]}, c=1.0, window=2)
    # i=1: every bonus is c*sqrt(ln 1 / 1) = 0 and every U = 0 -> earliest cluster, earliest value.
    assert bandit.select() == ("a", 1)
    bandit.update(1.0)  # a: N=2, U=1 ; a/1: N=2, U=1
    # i=2, ln 2 = 0.693147: a = 1 + sqrt(0.693/2) = 1.5887 ; b = 0 + sqrt(0.693/1) = 0.8326 -> a
    # inside a: value 1 = 1.5887, value 2 = 0.8326 -> 1
    assert bandit.select() == ("a", 1)
    s = bandit.scalars()
    assert s["ultho/ucb/a"] == pytest.approx(1.588705, abs=1e-5)
    assert s["ultho/bonus/b"] == pytest.approx(0.832555, abs=1e-5)
    assert s["ultho/ucb/a/2"] == pytest.approx(0.832555, abs=1e-5)
    assert s["ultho/utility/a/1"] == 1.0
    bandit.update(-1.0)  # a: window [1, -1], U = 0, N = 3
    # i=3, ln 3 = 1.098612: a = 0 + sqrt(1.0986/3) = 0.6051 ; b = sqrt(1.0986) = 1.0481 -> b
    assert bandit.select() == ("b", 10)
    bandit.update(0.5)  # b: U = 0.5, N = 2
    # i=4, ln 4 = 1.386294: a = sqrt(1.3863/3) = 0.6798 ; b = 0.5 + sqrt(1.3863/2) = 1.3326 -> b
    assert bandit.select() == ("b", 10)
    bandit.update(0.0)  # b: window [0.5, 0], U = 0.25, N = 3
    # i=5, ln 5 = 1.609438: a = sqrt(1.6094/3) = 0.7324 ; b = 0.25 + 0.7324 = 0.9824 -> b
    assert bandit.select() == ("b", 10)
    bandit.update(3.0)  # W = 2 evicts 0.5: window [0, 3], U = 1.5, N = 4
    assert bandit.utilities() == {"a": 0.0, "b": 1.5}
    # i=6, ln 6 = 1.791759: a = sqrt(1.7918/3) = 0.7728 ; b = 1.5 + sqrt(1.7918/4) = 2.1693 -> b
    assert bandit.select() == ("b", 10)
    assert bandit.scalars()["ultho/ucb/b"] == pytest.approx(2.169283, abs=1e-5)
    assert bandit.selections() == {"a": 2, "b": 3}  # the pending 6th selection is not counted yet
    assert bandit.value_selections() == {"a": [2, 0], "b": [3]}
    assert bandit.cluster_of_interest() == "b"
    assert bandit.neglected_cluster_of_interest() == "a"


def test_value_level_sequence_ties_and_global_log_term():
    bandit = ULTHO({"lr": [0.1, 0.2, 0.3]}, c=2.0, window=10)
    utilities = [0.2, 0.1, 0.9, 0.7]
    chosen = []
    for u in utilities:
        chosen.append(bandit.select()[1])
        bandit.update(u)
    # i=1 -> 0.1.  i=2: 0.1 -> 0.2 + 2*sqrt(0.6931/2) = 1.3774, 0.2 and 0.3 tie at 2*sqrt(0.6931) = 1.6651
    # -> the earlier, 0.2.  i=3: 0.1 -> 0.2 + 2*sqrt(1.0986/2) = 1.6823, 0.2 -> 1.5823, 0.3 -> 2.0963 -> 0.3.
    # i=4: bonus(N=2) = 2*sqrt(1.3863/2) = 1.6651: 1.8651, 1.7651, 0.9 + 1.6651 = 2.5651 -> 0.3.
    assert chosen == [0.1, 0.2, 0.3, 0.3]
    # i=5: bonus(N=2) = 2*sqrt(1.6094/2) = 1.7941, bonus(N=3) = 2*sqrt(1.6094/3) = 1.4649
    # 0.1 -> 1.9941, 0.2 -> 1.8941, 0.3 -> U = (0.9+0.7)/2 = 0.8, 0.8 + 1.4649 = 2.2649 -> 0.3
    assert bandit.select() == ("lr", 0.3)
    s = bandit.scalars()
    assert s["ultho/ucb/lr/0.1"] == pytest.approx(1.994123, abs=1e-5)
    assert s["ultho/ucb/lr/0.3"] == pytest.approx(2.264894, abs=1e-5)
    assert s["ultho/count/lr/0.3"] == 2.0
    assert s["ultho/count/lr"] == 4.0
    assert s["ultho/utility/lr"] == pytest.approx(0.475)  # mean of all four credits (W = 10)
    assert s["ultho/selected_cluster"] == 0.0
    assert s["ultho/selected_value_index"] == 2.0
    assert s["ultho/selected_value"] == 0.3


def test_c_zero_is_greedy_after_first_credit():
    bandit = ULTHO({"x": [1, 2], "y": [3]}, c=0.0, window=5)
    assert bandit.select() == ("x", 1)
    bandit.update(-1.0)  # x's U drops below y's 0 and with c = 0 nothing else counts
    assert bandit.select() == ("y", 3)
    bandit.update(-0.5)
    assert bandit.select() == ("y", 3)  # -0.5 > -1


def test_scalar_tags_cover_every_arm():
    bandit = ULTHO({"learning_rate": [1e-3, 2.5e-3, 5e-3], "minibatch_size": [128, 256, 512]})
    s = bandit.scalars()
    assert s["ultho/selected_cluster"] == -1.0 and math.isnan(s["ultho/selected_value"])
    for kind in ("utility", "bonus", "ucb", "count"):
        for tag in ("learning_rate", "learning_rate/0.001", "learning_rate/0.0025", "learning_rate/0.005",
                    "minibatch_size", "minibatch_size/128", "minibatch_size/256", "minibatch_size/512"):
            assert s[f"ultho/{kind}/{tag}"] == 0.0
    assert s["ultho/credit_scale"] == 1.0 and math.isnan(s["ultho/last_credit"])
    assert len(s) == 4 * 8 + 5
    assert all(isinstance(v, float) for v in s.values())


def test_coi_noi_ties_go_to_earliest():
    bandit = ULTHO({"a": [1], "b": [2], "c": [3]}, c=1.0)
    # Nothing selected: all tie, COI = a, NOI = the earliest of the others.
    assert bandit.cluster_of_interest() == "a" and bandit.neglected_cluster_of_interest() == "b"
    for u in (0.0, 0.0):  # i=1 -> a (all zero); i=2: a = sqrt(ln2/2), b = c = sqrt(ln 2) -> b
        bandit.select()
        bandit.update(u)
    assert bandit.selections() == {"a": 1, "b": 1, "c": 0}
    assert bandit.cluster_of_interest() == "a"
    assert bandit.neglected_cluster_of_interest() == "c"


def test_noi_differs_from_coi_after_a_strict_rotation():
    # c=5 with credits in [0, 1]: the bonus dominates and the bandit rotates a, b, c, a, b, c, ...
    bandit = ULTHO({"a": [1], "b": [2], "c": [3]}, c=5.0)
    chosen = []
    for _ in range(9):
        chosen.append(bandit.select()[0])
        bandit.update(0.5)
    assert chosen == ["a", "b", "c"] * 3
    assert bandit.selections() == {"a": 3, "b": 3, "c": 3}
    assert (bandit.cluster_of_interest(), bandit.neglected_cluster_of_interest()) == ("a", "b")


def test_summary_holds_the_space_the_options_the_choices_and_the_clusters_of_interest():
    bandit = ULTHO({"lr": [0.1, 0.2], "mb": [32]}, c=1.0, window=3, exp3_eta=0.25)
    # i=1 -> lr/0.1 (all zero); i=2: lr = 1 + sqrt(ln2/2) = 1.589, mb = sqrt(ln 2) = 0.833 -> lr; inside lr,
    # 0.1 = 1 + 0.589 against 0.2 = 0 + 0.833 -> 0.1.
    for credit in (1.0, 1.0):
        bandit.select()
        bandit.update(credit)
    summary = bandit.summary("return")
    # The keys, in the order summary.json has always had them.
    assert list(summary) == ["search_space", "c", "window", "utility", "strategy", "credit", "scale", "exp3_eta",
                             "selections", "value_selections", "coi", "noi"]
    assert summary == {
        "search_space": {"lr": [0.1, 0.2], "mb": [32]}, "c": 1.0, "window": 3, "utility": "return",
        "strategy": "ucb", "credit": "level", "scale": "none", "exp3_eta": 0.25,
        "selections": {"lr": 2, "mb": 0}, "value_selections": {"lr": [2, 0], "mb": [0]}, "coi": "lr", "noi": "mb",
    }
    assert json.loads(json.dumps(summary)) == summary  # what summary.json holds is what the method returns


def test_clusters_of_interest_rule():
    assert clusters_of_interest({"lr": 81, "mb": 81, "vf": 81}) == ("lr", "mb")
    assert clusters_of_interest({"lr": 5, "mb": 9, "vf": 9}) == ("mb", "lr")
    assert clusters_of_interest({"lr": 9, "mb": 5, "vf": 5}) == ("lr", "mb")
    assert clusters_of_interest({"lr": 7, "mb": 9, "vf": 2}) == ("mb", "vf")
    assert clusters_of_interest({"lr": 4, "mb": 4}) == ("lr", "mb")
    assert clusters_of_interest({"only": 3}) == ("only", "only")
    with pytest.raises(ValueError):
        clusters_of_interest({})


def test_format_value_labels():
    assert format_value(128) == "128"
    assert format_value(2.5e-4) == "0.00025"
    assert format_value(1.0) == "1.0"
    assert format_value(1e-5) == "1e-05"


# ----------------------------------------------------------------------------------------------------------
# Properties
# ----------------------------------------------------------------------------------------------------------

spaces = st.lists(st.integers(min_value=1, max_value=4), min_size=1, max_size=5).map(
    lambda sizes: {f"k{i}": [float(j + 10 * i) for j in range(n)] for i, n in enumerate(sizes)}
)
utilities = st.lists(st.floats(min_value=-1e3, max_value=1e3, allow_nan=False), min_size=1, max_size=60)


@settings(max_examples=150, deadline=None)
@given(space=spaces, us=utilities, c=st.sampled_from([0.0, 1.0, 5.0]), window=st.integers(1, 12))
def test_properties_counts_windows_and_argmax(space, us, c, window):
    bandit = ULTHO(space, c=c, window=window)
    names = list(space)
    for step, u in enumerate(us, start=1):
        name, value = bandit.select()
        s = bandit.scalars()
        # The chosen cluster has the highest bound; any cluster before it has a strictly lower one.
        k = names.index(name)
        bounds = [s[f"ultho/ucb/{n}"] for n in names]
        assert bounds[k] == max(bounds) and all(b < bounds[k] for b in bounds[:k])
        vbounds = [s[f"ultho/ucb/{name}/{format_value(v)}"] for v in space[name]]
        j = space[name].index(value)
        assert vbounds[j] == max(vbounds) and all(b < vbounds[j] for b in vbounds[:j])
        bandit.update(u)
        counts = bandit.selections()
        assert sum(counts.values()) == step == bandit.num_selections
        for n, per_value in bandit.value_selections().items():
            assert sum(per_value) == counts[n]
        state = bandit.state_dict()
        for arm in state["clusters"] + [a for arms in state["values"] for a in arms]:
            assert len(arm["credits"]) <= window
            assert len(arm["credits"]) == min(arm["count"] - 1, window)


@settings(max_examples=60, deadline=None)
@given(space=spaces, us=utilities, cut=st.integers(0, 60), pending=st.booleans(), window=st.integers(1, 6))
def test_state_dict_round_trip_gives_identical_future(space, us, cut, pending, window):
    cut = min(cut, len(us))
    original = ULTHO(space, c=1.0, window=window)
    for u in us[:cut]:
        original.select()
        original.update(u)
    if pending:
        original.select()
    restored = ULTHO.from_state_dict(json.loads(json.dumps(original.state_dict())))
    assert restored.state_dict() == original.state_dict()
    assert restored.scalars().keys() == original.scalars().keys()
    for bandit in (original, restored):
        if not pending:
            bandit.select()
    for u in us[cut:] + us:
        assert original.pending == restored.pending
        original.update(u)
        restored.update(u)
        assert original.select() == restored.select()
        assert original.scalars() == restored.scalars()


def test_load_state_dict_into_existing_bandit():
    a = ULTHO({"lr": [1, 2, 3]}, c=1.0, window=3)
    for u in (0.5, 0.1, 0.9):
        a.select()
        a.update(u)
    b = ULTHO({"lr": [1, 2, 3]}, c=1.0, window=3)
    b.load_state_dict(a.state_dict())
    assert b.select() == a.select()


# ----------------------------------------------------------------------------------------------------------
# Errors
# ----------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "space, c, window, message",
    [
        ({}, 5.0, 10, "empty search space"),
        ({"lr": []}, 5.0, 10, "'lr' has no candidate values"),
        ({"lr": [0.1, 0.1]}, 5.0, 10, "lists the value 0.1 twice"),
        ({"mb": [128, 128.0]}, 5.0, 10, "twice"),
        ({"lr": [0.1, float("nan")]}, 5.0, 10, "not finite"),
        ({"lr": [0.1, float("inf")]}, 5.0, 10, "not finite"),
        ({"lr": ["fast"]}, 5.0, 10, "not a number"),
        ({"lr": [0.1]}, -1.0, 10, "c=-1.0"),
        ({"lr": [0.1]}, float("inf"), 10, "c=inf"),
        ({"lr": [0.1]}, float("nan"), 10, "c=nan"),
        ({"lr": [0.1]}, 5.0, 0, "window=0"),
        ({"lr": [0.1]}, 5.0, 2.5, "window=2.5"),
    ],
)
def test_construction_errors(space, c, window, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(")):
        ULTHO(space, c=c, window=window)


def test_update_without_selection_and_double_select():
    bandit = ULTHO({"lr": [0.1, 0.2]})
    with pytest.raises(RuntimeError, match="without a pending selection"):
        bandit.update(1.0)
    bandit.select()
    with pytest.raises(RuntimeError, match="twice without update"):
        bandit.select()


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf"), "1.0", None])
def test_non_finite_utility_enters_no_window(bad):
    bandit = ULTHO({"lr": [0.1, 0.2]}, window=3)
    bandit.select()
    before = bandit.state_dict()
    with pytest.raises(ValueError, match="not a finite number"):
        bandit.update(bad)
    assert bandit.state_dict() == before  # still pending, nothing credited
    bandit.update(2.0)
    assert bandit.utilities() == {"lr": 2.0}


@pytest.mark.parametrize(
    "items, message",
    [
        ([], "empty search space"),
        (["momentum"], "unknown cluster 'momentum'"),
        (["momentum=0.9"], "unknown cluster 'momentum'"),
        (["=0.1"], "malformed cluster item '=0.1'"),
        (["vf_coef="], "malformed cluster item 'vf_coef='"),
        (["vf_coef=0.5,,1"], "malformed cluster item 'vf_coef=0.5,,1'"),
        (["vf_coef=0.5,big"], "'big' is not a number"),
        (["vf_coef=0.5,nan"], "not a finite number"),
        (["vf_coef=0.5,0.5"], "twice"),
        (["learning_rate", "learning_rate=0.1"], "'learning_rate' is given twice"),
        (["ent_coef"], "'ent_coef' has no default values"),
    ],
)
def test_parse_clusters_errors(items, message):
    defaults = {"learning_rate": [1e-3, 2.5e-3], "vf_coef": [0.25, 0.5, 1.0]}
    with pytest.raises(ValueError, match=message):
        parse_clusters(items, defaults, allowed=["learning_rate", "vf_coef", "ent_coef"])


def test_parse_clusters_defaults_explicit_values_and_order():
    defaults = {"learning_rate": [1e-3, 2.5e-3], "minibatch_size": [128, 256], "vf_coef": [0.25, 0.5, 1.0]}
    space = parse_clusters(["vf_coef=0.1, 0.2", "learning_rate", "minibatch_size=64,1e2"], defaults)
    assert space == {"vf_coef": [0.1, 0.2], "learning_rate": [1e-3, 2.5e-3], "minibatch_size": [64, 100.0]}
    assert list(space) == ["vf_coef", "learning_rate", "minibatch_size"]
    assert isinstance(space["minibatch_size"][0], int)


def _run_state():
    bandit = ULTHO({"lr": [1, 2], "mb": [3]}, c=1.0, window=2)
    for u in (1.0, 2.0, 3.0):
        bandit.select()
        bandit.update(u)
    return bandit.state_dict()


@pytest.mark.parametrize(
    "corrupt, message",
    [
        (lambda s: s.update(search_space={"lr": [1, 2]}), "search space"),
        (lambda s: s.update(search_space={"lr": [1, 5], "mb": [3]}), "search space"),
        (lambda s: s.update(c=2.0), "c=2.0"),
        (lambda s: s.update(window=3), "window=3"),
        (lambda s: s.update(format=99), "format"),
        (lambda s: s.update(num_selections=7), "selections"),
        (lambda s: s.update(pending=[5, 0], num_selections=4), "outside its search space"),
        (lambda s: s["clusters"][0].update(count=0), "count"),
        (lambda s: s["clusters"][0].update(credits=[1.0, 2.0, 3.0]), "credits"),
        (lambda s: s["clusters"][0].update(count=9), "add up"),
        (lambda s: s["values"][0].pop(), "number of arms"),
        (lambda s: s.pop("clusters"), "malformed"),
    ],
)
def test_mismatched_or_corrupt_state_dict(corrupt, message):
    state = _run_state()
    corrupt(state)
    target = ULTHO({"lr": [1, 2], "mb": [3]}, c=1.0, window=2)
    before = target.state_dict()
    with pytest.raises(ValueError, match=message):
        target.load_state_dict(state)
    assert target.state_dict() == before


# ----------------------------------------------------------------------------------------------------------
# Variants: credit transforms, running scale, Thompson sampling, Exp3
# ----------------------------------------------------------------------------------------------------------


def test_improvement_credit_and_running_scale_by_hand():
    bandit = ULTHO({"a": [1], "b": [2]}, c=1.0, window=10, credit="improvement", scale="running")
    with pytest.raises(ValueError, match="needs select\\(before="):
        bandit.select()
    assert bandit.select(before=1.0) == ("a", 1)  # every bound 0: the earliest
    assert bandit.update(1.5) == 0.5  # the change since the choice, not the level 1.5
    assert math.isnan(bandit.credit_scale)  # one credit: no spread yet, so utilities count as 0
    # i = 2: a = 0 + sqrt(ln 2 / 2) = 0.5887, b = 0 + sqrt(ln 2) = 0.8326 -> b
    assert bandit.select(before=1.5) == ("b", 2)
    assert bandit.update(1.2) == pytest.approx(-0.3)
    # credits 0.5, -0.3: sample std sqrt(0.32) = 0.5657; in those units U_a = 0.8839, U_b = -0.5303
    sigma = math.sqrt(0.32)
    assert bandit.credit_scale == pytest.approx(sigma)
    s = bandit.scalars()
    assert s["ultho/utility/a"] == 0.5 and s["ultho/utility/b"] == pytest.approx(-0.3)  # the credits' own units
    assert s["ultho/ucb/a"] == pytest.approx(0.5 / sigma + math.sqrt(math.log(2) / 2))
    assert s["ultho/ucb/b"] == pytest.approx(-0.3 / sigma + math.sqrt(math.log(2) / 2))
    assert s["ultho/last_credit"] == pytest.approx(-0.3)
    # i = 3: a = 0.8839 + sqrt(ln 3 / 2) = 1.6250, b = -0.5303 + 0.7411 = 0.2108 -> a
    assert bandit.select(before=1.2) == ("a", 1)


@pytest.mark.parametrize("strategy", ["ucb", "ts", "exp3"])
def test_running_scale_makes_choices_independent_of_the_credits_units(strategy):
    measures = [math.sin(0.9 * k) + 0.05 * k for k in range(120)]
    chosen = []
    for units in (0.01, 1.0, 100.0):
        bandit = ULTHO({"lr": [1, 2, 3], "mb": [4, 5]}, c=1.0, window=20, strategy=strategy, credit="improvement",
                       scale="running", seed=2)
        picks = []
        for k in range(len(measures) - 1):
            picks.append(bandit.select(before=units * measures[k]))
            bandit.update(units * measures[k + 1])
        chosen.append(picks)
    assert chosen[0] == chosen[1] == chosen[2]
    assert len(set(chosen[1])) > 1


def test_scale_none_keeps_the_papers_bounds():
    plain, scaled = ULTHO({"a": [1], "b": [2]}, c=1.0), ULTHO({"a": [1], "b": [2]}, c=1.0, scale="none")
    for u in (3.0, -2.0, 7.5, 0.25):
        assert plain.select() == scaled.select()
        plain.update(u)
        scaled.update(u)
        assert plain.scalars() == scaled.scalars()
    assert plain.credit_scale == 1.0


# Random(3).gauss(0, 1), the first nine draws: three per selection (two clusters, then the chosen one's value).
GAUSS_3 = [0.09470803828730423, 1.2500243810835503, -0.931378367720707, 0.9923772805192402, -0.25915453769343405,
           -0.26151098398117395, 1.8997252784647571, 0.1575370716337192, -0.042924253792244314]


def test_thompson_sampling_sequence_by_hand():
    import random

    generator = random.Random(3)
    assert [generator.gauss(0.0, 1.0) for _ in GAUSS_3] == GAUSS_3
    bandit = ULTHO({"a": [1], "b": [2]}, strategy="ts", seed=3)
    # 1: a = 0 + 0.0947 / 1, b = 0 + 1.2500 / 1 -> b
    assert bandit.select() == ("b", 2)
    bandit.update(0.5)
    s = bandit.scalars()
    assert (s["ultho/ts_mean/b"], s["ultho/ts_std/b"], s["ultho/ts_std/a"]) == (0.5, 1 / math.sqrt(2), 1.0)
    # 2: a = 0 + 0.9924 / 1 = 0.9924, b = 0.5 - 0.2592 / sqrt(2) = 0.3167 -> a
    assert bandit.select() == ("a", 1)
    bandit.update(-1.0)
    # 3: a = -1 + 1.8997 / sqrt(2) = 0.3433, b = 0.5 + 0.1575 / sqrt(2) = 0.6114 -> b
    assert bandit.select() == ("b", 2)
    assert "ultho/ucb/a" not in bandit.scalars()


def test_exp3_sequence_by_hand():
    import random

    draws = [0.13436424411240122, 0.8474337369372327, 0.763774618976614, 0.2550690257394217, 0.49543508709194095]
    generator = random.Random(1)
    assert [generator.random() for _ in draws] == draws
    bandit = ULTHO({"a": [1], "b": [2]}, window=2, strategy="exp3", seed=1, exp3_eta=0.5)
    # 1: S = (0, 0), p = (0.5, 0.5); draw 0.134 < 0.5 -> a (the value level, one arm, has p = 1)
    assert bandit.scalars()["ultho/probability/a"] == 0.5
    assert bandit.select() == ("a", 1)
    # credit 2: reward sigmoid(2 - 0) = 0.88079708 (no credits before: mean 0; unscaled); S discounted by
    # 1 - 1/2, then S_a += 1 - (1 - 0.88079708) / 0.5 = 0.76159416 and S_b += 1
    bandit.update(2.0)
    p_a = 1 / (1 + math.exp(-0.5 * (0.76159416 - 1.0)))
    assert bandit.scalars()["ultho/probability/a"] == pytest.approx(p_a, abs=1e-8)  # 0.47023451
    # 2: draw 0.764 >= p_a -> b, drawn with probability 0.52976549
    assert bandit.select() == ("b", 2)
    # credit -1 against the mean 2 of the credits before: reward sigmoid(-3) = 0.04742587;
    # S_a = 0.76159416 / 2 + 1 = 1.38079708, S_b = 1 / 2 + 1 - (1 - 0.04742587) / 0.52976549 = -0.29810527
    bandit.update(-1.0)
    p_a = 1 / (1 + math.exp(-0.5 * (1.38079708 + 0.29810527)))
    assert bandit.scalars()["ultho/probability/a"] == pytest.approx(p_a, abs=1e-8)  # 0.69834961
    # 3: draw 0.495 < 0.698 -> a
    assert bandit.select() == ("a", 1)


VARIANTS = [dict(strategy=s, credit=k, scale=x) for s in ("ucb", "ts", "exp3", "round-robin")
            for k in ("level", "improvement") for x in ("none", "running")]


@pytest.mark.parametrize("options", VARIANTS, ids=lambda o: "-".join(o.values()))
def test_every_variant_round_trips_exactly_through_json(options):
    space = {"lr": [1e-3, 2e-3, 5e-3], "mb": [64, 128], "vf": [0.5]}
    measures = [math.sin(1.7 * k) + 0.01 * k for k in range(80)]
    original = ULTHO(space, c=2.0, window=4, seed=11, **options)
    for k in range(30):
        original.select(before=measures[k])
        original.update(measures[k + 1])
    original.select(before=measures[30])  # a pending selection, its `before` included
    restored = ULTHO.from_state_dict(json.loads(json.dumps(original.state_dict())))
    assert restored.state_dict() == original.state_dict() and restored.options() == original.options()
    for k in range(30, 79):
        assert original.update(measures[k + 1]) == restored.update(measures[k + 1])
        assert original.select(before=measures[k + 1]) == restored.select(before=measures[k + 1])
        assert original.scalars() == restored.scalars()


def test_options_must_match_when_loading():
    state = ULTHO({"lr": [1, 2]}, strategy="ts", seed=5).state_dict()
    with pytest.raises(ValueError, match="strategy='ts'.*strategy='ucb'"):
        ULTHO({"lr": [1, 2]}).load_state_dict(state)
    with pytest.raises(ValueError, match="seed=5.*seed=6"):
        ULTHO({"lr": [1, 2]}, strategy="ts", seed=6).load_state_dict(state)


def test_a_format_1_state_loads_as_the_papers_bandit():
    """Checkpoints written before the variants existed keep resuming."""
    bandit = ULTHO({"a": [1, 2], "b": [3]}, c=1.0, window=3)
    for u in (0.5, 0.25, 1.0):
        bandit.select()
        bandit.update(u)
    bandit.select()
    state = bandit.state_dict()
    old = {key: state[key] for key in ("search_space", "c", "window", "num_selections", "pending", "last")}
    old |= {"format": 1, "clusters": [{"count": a["count"], "credits": a["credits"]} for a in state["clusters"]],
            "values": [[{"count": a["count"], "credits": a["credits"]} for a in arms] for arms in state["values"]]}
    restored = ULTHO.from_state_dict(old)
    restored.update(0.75)
    bandit.update(0.75)
    assert restored.select() == bandit.select() and restored.scalars() == bandit.scalars()
    with pytest.raises(ValueError, match="strategy='ucb'"):
        ULTHO({"a": [1, 2], "b": [3]}, c=1.0, window=3, strategy="exp3").load_state_dict(old)


@pytest.mark.parametrize("options, message", [
    (dict(strategy="greedy"), "strategy='greedy' is not one of ucb, ts, exp3"),
    (dict(credit="delta"), "credit='delta' is not one of level, improvement"),
    (dict(scale="max"), "scale='max' is not one of none, running"),
    (dict(seed=1.5), "seed=1.5 must be an integer"),
    (dict(exp3_eta=0.0), "exp3_eta=0.0 must be a finite number > 0"),
])
def test_bad_options_are_refused(options, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        ULTHO({"lr": [1, 2]}, **options)


def _stationary_pulls(options: dict, scale: float, seed: int, pulls: int = 250) -> dict[tuple[int, int], int]:
    """Pulls of each (cluster, value) arm on a stationary two-level problem whose credits are ``scale`` times
    a unit problem: means 0, 0.5, 1 in cluster x and 1, 1.5, 3 in cluster y (the best arm: y's third value),
    Gaussian noise of standard deviation 1."""
    import random

    means = {"x": [0.0, 0.5, 1.0], "y": [1.0, 1.5, 3.0]}
    noise = random.Random(1000 + seed)
    bandit = ULTHO({"x": [0, 1, 2], "y": [0, 1, 2]}, seed=seed, **options)
    pulls_of: dict[tuple[int, int], int] = {}
    for _ in range(pulls):
        cluster, value = bandit.select()
        key = (list(means).index(cluster), value)
        pulls_of[key] = pulls_of.get(key, 0) + 1
        bandit.update(scale * (means[cluster][value] + noise.gauss(0.0, 1.0)))
    return pulls_of


@pytest.mark.parametrize("strategy", ["ucb", "ts", "exp3"])
@pytest.mark.parametrize("scale", [0.01, 1.0, 100.0])
def test_with_running_scale_the_best_arm_is_chosen_most_at_every_credit_scale(strategy, scale):
    """250 pulls (MiniGrid's 244 iterations), W = 50, c = 5 for UCB, five seeds: the best arm gets the most pulls
    in every one."""
    for seed in range(5):
        pulls = _stationary_pulls(dict(c=5.0, window=50, strategy=strategy, scale="running"), scale, seed)
        assert max(pulls, key=pulls.get) == (1, 2), (seed, pulls)


@pytest.mark.parametrize("seed", range(5))
def test_the_papers_ucb_depends_on_the_credit_scale(seed):
    """Unscaled, c = 5 swamps credits of 0.01: an even rotation. Credits of 100 swamp c = 5: the first value
    of the first cluster credited above 0 keeps every pull, and the best value is never tried."""
    small = _stationary_pulls(dict(c=5.0, window=50), 0.01, seed)
    assert len(small) == 6 and max(small.values()) - min(small.values()) <= 2  # 250 pulls: 41 to 43 each
    large = _stationary_pulls(dict(c=5.0, window=50), 100.0, seed)
    assert (1, 2) not in large and max(large.values()) >= 248


# ----------------------------------------------------------------------------------------------------------
# The authors' timing (withdraw) and the round-robin control.
# ----------------------------------------------------------------------------------------------------------


def test_withdraw_gives_back_the_selection_number_as_the_authors_ucb_counts():
    # The authors' flat UCB over PPO epochs {10, 5}: their first choice is never credited, and their log term
    # counts credits + 1, so the second choice is made with ln 1 = 0 as well. c = 5, W = 10.
    bandit = ULTHO({"update_epochs": [10, 5]}, c=5.0, window=10)
    assert bandit.select() == ("update_epochs", 10)  # iteration 1: i = 1, every bound 0 -> the first value
    bandit.withdraw()
    assert bandit.num_selections == 0 and bandit.pending is None and bandit.selections() == {"update_epochs": 0}
    assert bandit.select() == ("update_epochs", 10)  # iteration 2: i = 1 again -> 10, credited at once
    assert bandit.update(0.30) == 0.30  # 10: N = 2, U = 0.30
    # iteration 3, i = 2, ln 2 = 0.693147: 10 -> 0.30 + 5*sqrt(0.6931/2) = 3.2435 ; 5 -> 5*sqrt(0.6931) = 4.1628
    assert bandit.select() == ("update_epochs", 5)
    assert bandit.scalars()["ultho/ucb/update_epochs/10"] == pytest.approx(3.243525, abs=1e-5)
    assert bandit.scalars()["ultho/ucb/update_epochs/5"] == pytest.approx(4.162773, abs=1e-5)
    bandit.update(0.10)  # 5: N = 2, U = 0.10
    # iteration 4, i = 3, ln 3 = 1.098612: 10 -> 0.30 + 5*sqrt(1.0986/2) = 4.0058 ; 5 -> 0.10 + 3.7058 -> 10
    assert bandit.select() == ("update_epochs", 10)
    assert bandit.scalars()["ultho/ucb/update_epochs/5"] == pytest.approx(3.805760, abs=1e-5)
    bandit.update(0.50)
    assert bandit.value_selections() == {"update_epochs": [2, 1]}
    assert bandit.utilities() == {"update_epochs": pytest.approx(0.30)}  # the cluster: every credit
    assert bandit.scalars()["ultho/utility/update_epochs/10"] == pytest.approx(0.40)  # 10's own: 0.30, 0.50


def test_withdraw_needs_a_pending_selection_and_survives_a_state_round_trip():
    bandit = ULTHO({"lr": [1, 2]}, c=1.0)
    with pytest.raises(RuntimeError, match="withdraw"):
        bandit.withdraw()
    bandit.select()
    bandit.withdraw()
    with pytest.raises(RuntimeError, match="withdraw"):
        bandit.withdraw()
    restored = ULTHO.from_state_dict(json.loads(json.dumps(bandit.state_dict())))
    assert restored.state_dict() == bandit.state_dict() and restored.select() == bandit.select() == ("lr", 1)


def test_round_robin_takes_clusters_and_their_values_in_turn_whatever_the_credits():
    bandit = ULTHO({"lr": [1, 2, 3], "mb": [64, 128], "vf": [0.5]}, strategy="round-robin")
    chosen = []
    for credit in [100.0, -5.0, 3.0, 1e6, -1e6, 0.0, 7.0, 7.0, -2.0]:
        chosen.append(bandit.select())
        bandit.update(credit)
    assert chosen == [("lr", 1), ("mb", 64), ("vf", 0.5), ("lr", 2), ("mb", 128), ("vf", 0.5), ("lr", 3),
                      ("mb", 64), ("vf", 0.5)]
    assert bandit.selections() == {"lr": 3, "mb": 3, "vf": 3}
    tags = bandit.scalars()
    assert tags["ultho/count/mb/64"] == 2.0 and tags["ultho/utility/lr"] == pytest.approx((100.0 + 1e6 + 7.0) / 3)
    assert not any(tag.startswith(("ultho/ucb", "ultho/bonus", "ultho/ts_", "ultho/probability")) for tag in tags)


def test_round_robin_over_one_cluster_is_the_authors_rotation():
    bandit = ULTHO({"update_epochs": [10, 5]}, strategy="round-robin")
    chosen = []
    for k in range(6):
        chosen.append(bandit.select()[1])
        bandit.update(float(k))
    assert chosen == [10, 5, 10, 5, 10, 5]
