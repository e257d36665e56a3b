"""The ULTHO hierarchical bandit (Yuan et al., ICCV 2025, Algorithm 1, Eqs. 4-7), and opt-in variants of it.

A search space is an ordered mapping ``cluster name -> candidate values``; the cluster name is the PPO
setting the value overrides (``args.<name> = value``). Every iteration a training loop calls
:meth:`ULTHO.select` once and, after the update that used the chosen value, credits it with
:meth:`ULTHO.update`. Selections and credits strictly alternate.

Conventions this module fixes (docs/bandit.md):

* every cluster and every value starts with N = 1 and U = 0 and keeps a FIFO window of its last W credits;
* selection number i (1, 2, 3, ...) uses ``ln(i)`` in the bonus at *both* levels (Eqs. 4 and 5);
* ties go to the earliest cluster / value, so the first selection is the first cluster's first value;
* U is the mean of the credits in the window (Eq. 6), of those present while fewer than W.

The defaults are the paper's algorithm: ``strategy="ucb"``, ``credit="level"``, ``scale="none"``. The variants
(docs/strategies.md) keep the same two-level structure and the same arm bookkeeping:

* ``credit="improvement"`` credits a choice with the utility minus the one measured before it took effect
  (``select(before=...)``), not with its level, which rises during training whatever was chosen;
* ``scale="running"`` divides every utility by the running standard deviation of all credits so far, so that
  c (and the Thompson-sampling and Exp3 arithmetic) means the same whatever the credits' units;
* ``strategy="ts"``: Gaussian Thompson sampling on each arm's window; ``strategy="exp3"``: Exp3 with weights
  discounted by 1 - 1/W, on credits mapped to [0, 1]. Both draw from a seeded generator kept in the state;
* ``strategy="round-robin"``: the control without a bandit: the least-chosen cluster, then its least-chosen value
  (ties to the earliest), so the clusters and each cluster's values come in turn whatever the credits say.

:meth:`ULTHO.withdraw` drops a selection uncredited, as the authors' public code does with a run's first choice.

Pure Python: one ``select()`` + ``update()`` pair over 4 clusters x 3 values costs a few microseconds
(``benchmarks/bench_bandit.py``).
"""

from __future__ import annotations

import math
import random
from collections import deque
from typing import Any, Literal, Mapping, Sequence

Number = int | float
SearchSpace = dict[str, list[Number]]
Strategy = Literal["ucb", "ts", "exp3", "round-robin"]
Credit = Literal["level", "improvement"]
Scale = Literal["none", "running"]

STRATEGIES: tuple[str, ...] = ("ucb", "ts", "exp3", "round-robin")
CREDITS: tuple[str, ...] = ("level", "improvement")
SCALES: tuple[str, ...] = ("none", "running")
STATE_FORMAT = 2


def format_value(value: Number) -> str:
    """The label of a candidate value in TensorBoard tags and summaries (``0.001``, ``128``).

    Python's shortest round-trip representation, so distinct values never share a label.
    """
    return str(value) if isinstance(value, int) else repr(float(value))


def _as_number(value: Any, where: str) -> Number:
    if hasattr(value, "item") and not isinstance(value, (int, float)):
        value = value.item()  # numpy scalars
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where}: candidate value {value!r} is not a number")
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"{where}: candidate value {value!r} is not finite")
    return value


def _as_finite(value: Any, what: str) -> float:
    if hasattr(value, "item") and not isinstance(value, (int, float)):
        value = value.item()
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{what} {value!r} is not a finite number")
    return float(value)


def validate_search_space(search_space: Mapping[str, Sequence[Any]]) -> SearchSpace:
    """Checks a search space and returns it as a plain ``{name: [int | float, ...]}`` dict, order kept.

    Raises ValueError naming the problem: no clusters, a bad name, a cluster without values, a value that
    is not a finite number, or a value listed twice in one cluster.
    """
    if not isinstance(search_space, Mapping) or len(search_space) == 0:
        raise ValueError("empty search space: give at least one cluster with at least one value")
    clean: SearchSpace = {}
    for name, values in search_space.items():
        if not isinstance(name, str) or not name.isidentifier():
            raise ValueError(f"cluster name {name!r} is not a valid setting name")
        if isinstance(values, (str, bytes)) or not isinstance(values, Sequence) or len(values) == 0:
            raise ValueError(f"cluster {name!r} has no candidate values")
        numbers = [_as_number(v, f"cluster {name!r}") for v in values]
        labels = [format_value(v) for v in numbers]
        for i, label in enumerate(labels):
            if label in labels[:i] or any(numbers[j] == numbers[i] for j in range(i)):
                raise ValueError(f"cluster {name!r} lists the value {label} twice")
        clean[name] = numbers
    return clean


def clusters_of_interest(selections: Mapping[str, int]) -> tuple[str, str]:
    """Eq. 7: ``(COI, NOI)`` from ``{cluster: times selected}`` in the search space's order.

    The COI is the most-selected cluster, the NOI the least-selected cluster *other than the COI*; ties go
    to the earliest cluster in the search space's order at both steps. So the two differ whenever there are
    two clusters or more, even when every cluster was selected equally often (a strict rotation gives COI =
    the first cluster, NOI = the second). With one cluster both are that cluster.

    Raises:
        ValueError: ``selections`` is empty.
    """
    names = list(selections)
    if not names:
        raise ValueError("no clusters: the COI and NOI need at least one")
    coi = max(names, key=lambda name: (selections[name], -names.index(name)))
    others = [name for name in names if name != coi] or [coi]
    noi = min(others, key=lambda name: (selections[name], names.index(name)))
    return coi, noi


class _Arm:
    """One arm (a cluster or a value): its count N, the FIFO window behind its utility U, and Exp3's estimate."""

    __slots__ = ("count", "credits", "utility", "exp3_sum")

    def __init__(self, window: int) -> None:
        self.count = 1  # N starts at 1 (Algorithm 1, line 3)
        self.credits: deque[float] = deque(maxlen=window)
        self.utility = 0.0  # U starts at 0
        self.exp3_sum = 0.0  # Exp3 only: S, the discounted estimate of the arm's summed rewards

    def credit(self, utility: float) -> None:
        """Eq. 6: push the credit into the window, U = window mean, N += 1."""
        self.credits.append(utility)
        self.utility = math.fsum(self.credits) / len(self.credits)
        self.count += 1

    def bonus(self, c: float, log_i: float) -> float:
        """The exploration term ``c * sqrt(ln(i) / N)`` of Eqs. 4 and 5."""
        return c * math.sqrt(log_i / self.count)

    def posterior_std(self) -> float:
        """Thompson sampling's spread of the mean, in credit-scale units: 1 / sqrt(1 + credits in the window)
        (a unit-variance Gaussian model with one prior pseudo-observation at U = 0)."""
        return 1.0 / math.sqrt(1 + len(self.credits))


def _first_best(scores: Sequence[float]) -> int:
    """Index of the highest score; the strict ``>`` gives ties to the earliest arm."""
    best, best_score = 0, -math.inf
    for index, score in enumerate(scores):
        if score > best_score:
            best, best_score = index, score
    return best


class ULTHO:
    """Hierarchical bandit over clusters of hyperparameter values (Algorithm 1), UCB by default.

    Args:
        search_space: ordered ``{cluster name: [candidate values]}``; names are the settings to override.
        c: exploration coefficient of Eqs. 4 and 5 (finite, >= 0); UCB only. The paper's grid is {1, 5}.
        window: W, the number of most recent credits averaged into a utility (Eq. 6). Paper: {10, 50, 100}.
            Exp3 discounts its weights by 1 - 1/W per update instead, so W is the memory of every strategy.
        strategy: ``"ucb"`` (Eqs. 4-5, the paper's), ``"ts"`` (Gaussian Thompson sampling), ``"exp3"``, or
            ``"round-robin"`` (the values in turn, credits recorded but never used: the control for all three).
        credit: ``"level"`` (the utility as measured, the paper's) or ``"improvement"`` (the utility minus the
            one given to :meth:`select` as ``before``).
        scale: ``"none"`` (the paper's) or ``"running"``: utilities divided by the running standard deviation
            of all credits so far (utilities count as 0 until two credits differ).
        seed: seed of the generator Thompson sampling and Exp3 draw from (UCB draws nothing).
        exp3_eta: Exp3's learning rate eta (> 0): its probabilities are softmax(eta * S).

    Raises:
        ValueError: an invalid search space or option.
    """

    def __init__(self, search_space: Mapping[str, Sequence[Any]], c: float = 5.0, window: int = 10,
                 strategy: Strategy = "ucb", credit: Credit = "level", scale: Scale = "none", seed: int = 0,
                 exp3_eta: float = 0.5) -> None:
        self.search_space = validate_search_space(search_space)
        if isinstance(c, bool) or not isinstance(c, (int, float)) or not math.isfinite(c) or c < 0:
            raise ValueError(f"exploration coefficient c={c!r} must be a finite number >= 0")
        if isinstance(window, bool) or not isinstance(window, int) or window < 1:
            raise ValueError(f"window={window!r} must be an integer >= 1")
        for name, given, allowed in (("strategy", strategy, STRATEGIES), ("credit", credit, CREDITS),
                                     ("scale", scale, SCALES)):
            if given not in allowed:
                raise ValueError(f"{name}={given!r} is not one of {', '.join(allowed)}")
        if isinstance(seed, bool) or not isinstance(seed, int):
            raise ValueError(f"seed={seed!r} must be an integer")
        if isinstance(exp3_eta, bool) or not isinstance(exp3_eta, (int, float)) or not (
                math.isfinite(exp3_eta) and exp3_eta > 0):
            raise ValueError(f"exp3_eta={exp3_eta!r} must be a finite number > 0")
        self.c = float(c)
        self.window = window
        self.strategy: Strategy = strategy
        self.credit_mode: Credit = credit
        self.scale_mode: Scale = scale
        self.seed = seed
        self.exp3_eta = float(exp3_eta)
        self.cluster_names = list(self.search_space)
        self._clusters = [_Arm(window) for _ in self.cluster_names]
        self._values = [[_Arm(window) for _ in vals] for vals in self.search_space.values()]
        self._num_selections = 0
        self._pending: tuple[int, int] | None = None
        self._last: tuple[int, int] | None = None
        self._pending_before: float | None = None
        self._pending_probabilities = (1.0, 1.0)  # of the pending cluster and value, for Exp3's estimate
        self._last_credit = math.nan
        self._rng = random.Random(seed)
        # Welford's running count, mean and sum of squared deviations of every credit so far.
        self._stats = [0, 0.0, 0.0]

    # ------------------------------------------------------------------ the algorithm
    def select(self, before: float | None = None) -> tuple[str, Number]:
        """Selection number i: a cluster, then a value inside it (UCB: Eqs. 4 and 5 with the same global i).

        Args:
            before: the utility measured now, before the choice takes effect (the same measure
                :meth:`update` will be given afterwards). Needed with ``credit="improvement"``, ignored otherwise.

        Returns ``(cluster name, value)``. The choice stays pending until :meth:`update` credits it.

        Raises:
            RuntimeError: the previous selection has not been credited yet.
            ValueError: ``credit="improvement"`` without a finite ``before``.
        """
        if self._pending is not None:
            raise RuntimeError("select() called twice without update(): credit the pending selection first")
        if self.credit_mode == "improvement":
            if before is None:
                raise ValueError("credit='improvement' needs select(before=<the utility measured now>)")
            before = _as_finite(before, "before")
        elif before is not None:
            before = _as_finite(before, "before")
        self._num_selections += 1
        log_i = math.log(self._num_selections)
        cluster, cluster_p = self._choose(self._clusters, log_i)
        value, value_p = self._choose(self._values[cluster], log_i)
        self._pending = self._last = (cluster, value)
        self._pending_before = before
        self._pending_probabilities = (cluster_p, value_p)
        name = self.cluster_names[cluster]
        return name, self.search_space[name][value]

    def update(self, utility: float) -> float:
        """Credits the pending selection (Eq. 6) for its cluster and its value; returns the credit.

        The paper's utility is the mean critic value of the updated policy, V-bar in Eq. 6. The credit is the
        utility (``credit="level"``) or the utility minus the pending selection's ``before``.

        Raises:
            RuntimeError: no selection is pending.
            ValueError: ``utility`` is not a finite number (nothing is credited then).
        """
        if self._pending is None:
            raise RuntimeError("update() without a pending selection: call select() first")
        try:
            utility = _as_finite(utility, "utility")
        except ValueError:
            raise ValueError(f"utility {utility!r} is not a finite number; the selection stays uncredited") from None
        credit = utility - self._pending_before if self.credit_mode == "improvement" else utility
        if not math.isfinite(credit):
            raise ValueError(f"credit {credit!r} is not finite; the selection stays uncredited")
        cluster, value = self._pending
        if self.strategy == "exp3":
            reward = self._exp3_reward(credit)
            self._exp3_credit(self._clusters, cluster, reward, self._pending_probabilities[0])
            self._exp3_credit(self._values[cluster], value, reward, self._pending_probabilities[1])
        self._clusters[cluster].credit(credit)
        self._values[cluster][value].credit(credit)
        count, mean, squares = self._stats
        count += 1
        delta = credit - mean
        mean += delta / count
        self._stats = [count, mean, squares + delta * (credit - mean)]
        self._pending = None
        self._pending_before = None
        self._last_credit = credit
        return credit

    def withdraw(self) -> None:
        """Drops the pending selection uncredited, as if it had not been made: its selection number i is given
        back (the next :meth:`select` is number i again) and no count or window changes. The value it chose may
        have been used all the same; it just earns nothing. The authors' public code treats a run's first choice
        so (``--ultho-utility authors-return``, docs/authors_code.md).

        Raises:
            RuntimeError: no selection is pending.
        """
        if self._pending is None:
            raise RuntimeError("withdraw() without a pending selection: call select() first")
        self._num_selections -= 1
        self._pending = None
        self._pending_before = None
        self._pending_probabilities = (1.0, 1.0)

    def _choose(self, arms: Sequence[_Arm], log_i: float) -> tuple[int, float]:
        """(index, probability with which it was drawn) of one level's choice under the strategy."""
        if self.strategy == "round-robin":  # the least-chosen arm; N counts credits, so the arms come in turn
            return _first_best([-arm.count for arm in arms]), 1.0
        if self.strategy == "ucb":  # Eqs. 4 and 5
            return _first_best([self._scaled(arm.utility) + arm.bonus(self.c, log_i) for arm in arms]), 1.0
        if self.strategy == "ts":
            return _first_best([self._scaled(arm.utility) + self._rng.gauss(0.0, 1.0) * arm.posterior_std()
                                for arm in arms]), 1.0
        probabilities = self._exp3_probabilities(arms)
        draw, total = self._rng.random(), 0.0
        for index, p in enumerate(probabilities):
            total += p
            if draw < total:
                return index, p
        return len(arms) - 1, probabilities[-1]  # draw within rounding of 1

    def _exp3_probabilities(self, arms: Sequence[_Arm]) -> list[float]:
        """softmax(eta * S), S being each arm's discounted estimate of its summed rewards."""
        top = max(arm.exp3_sum for arm in arms)
        weights = [math.exp(self.exp3_eta * (arm.exp3_sum - top)) for arm in arms]
        total = math.fsum(weights)
        return [w / total for w in weights]

    def _exp3_reward(self, credit: float) -> float:
        """The credit mapped to (0, 1): logistic of its distance from the mean of the credits before it, in
        units of the credit scale."""
        x = self._scaled(credit - self._stats[1])
        return 1.0 / (1.0 + math.exp(-x)) if x >= 0 else math.exp(x) / (1.0 + math.exp(x))  # no overflow

    def _scaled(self, utility: float) -> float:
        """``utility`` in units of the credit scale. With ``scale="running"`` and no spread among the credits
        yet (fewer than two, or all equal) it is 0: a single credit says nothing about the units."""
        if self.scale_mode == "none":
            return utility
        scale = self.credit_scale
        return 0.0 if math.isnan(scale) else utility / scale

    def _exp3_credit(self, arms: Sequence[_Arm], chosen: int, reward: float, probability: float) -> None:
        """Every estimate S discounted by 1 - 1/W, then raised by the loss-based importance-weighted reward
        estimate 1 - (1 - reward) / p for the chosen arm and 1 for the others (Lattimore and Szepesvari 2020,
        Eq. 11.6: unbiased, and lower-variance than reward / p)."""
        keep = 1.0 - 1.0 / self.window
        for index, arm in enumerate(arms):
            arm.exp3_sum = keep * arm.exp3_sum + 1.0 - ((1.0 - reward) / probability if index == chosen else 0.0)

    # ------------------------------------------------------------------ read-outs
    @property
    def num_selections(self) -> int:
        """i of the latest selection (0 before the first)."""
        return self._num_selections

    @property
    def pending(self) -> tuple[str, Number] | None:
        """The selection awaiting its credit, or None."""
        if self._pending is None:
            return None
        cluster, value = self._pending
        name = self.cluster_names[cluster]
        return name, self.search_space[name][value]

    @property
    def credit_scale(self) -> float:
        """What utilities are divided by: 1 with ``scale="none"``; else the sample standard deviation of all
        credits so far (``nan`` while it is undefined or 0: fewer than two credits, or all of them equal)."""
        count, _, squares = self._stats
        if self.scale_mode == "none":
            return 1.0
        return math.sqrt(squares / (count - 1)) if count >= 2 and squares > 0 else math.nan

    @property
    def last_credit(self) -> float:
        """The latest credit after the transform (``nan`` before the first)."""
        return self._last_credit

    def options(self) -> dict[str, Any]:
        """The constructor's arguments other than the search space, as given (for summaries and records)."""
        return {"c": self.c, "window": self.window, "strategy": self.strategy, "credit": self.credit_mode,
                "scale": self.scale_mode, "seed": self.seed, "exp3_eta": self.exp3_eta}

    def selections(self) -> dict[str, int]:
        """``{cluster: times chosen and credited}``, i.e. N - 1 per cluster (the paper's N_end - 1)."""
        return {name: arm.count - 1 for name, arm in zip(self.cluster_names, self._clusters)}

    def value_selections(self) -> dict[str, list[int]]:
        """``{cluster: [times each value was chosen and credited]}`` in the search space's order."""
        return {name: [arm.count - 1 for arm in arms] for name, arms in zip(self.cluster_names, self._values)}

    def utilities(self) -> dict[str, float]:
        """``{cluster: U}``, the current window means."""
        return {name: arm.utility for name, arm in zip(self.cluster_names, self._clusters)}

    def cluster_of_interest(self) -> str:
        """Eq. 7: the cluster of interest (COI), the most-selected cluster (see :func:`clusters_of_interest`)."""
        return clusters_of_interest(self.selections())[0]

    def neglected_cluster_of_interest(self) -> str:
        """Eq. 7: the neglected cluster of interest (NOI), the least-selected other cluster (see
        :func:`clusters_of_interest`)."""
        return clusters_of_interest(self.selections())[1]

    def summary(self, utility: str) -> dict[str, Any]:
        """The bandit's part of a run's summary.json: its search space and options, what it chose and the
        clusters of interest (Eq. 7). ``utility`` names what the caller credits it with (e.g. ``"value"``), which
        the bandit itself never sees. The keys and their order are the scripts' (docs/scripts.md)."""
        return {
            "search_space": self.search_space,
            "c": self.c,
            "window": self.window,
            "utility": utility,
            "strategy": self.strategy,
            "credit": self.credit_mode,
            "scale": self.scale_mode,
            "exp3_eta": self.exp3_eta,
            "selections": self.selections(),
            "value_selections": self.value_selections(),
            "coi": self.cluster_of_interest(),
            "noi": self.neglected_cluster_of_interest(),
        }

    def scalars(self) -> dict[str, float]:
        """A flat ``{tag: float}`` for TensorBoard: one ``writer.add_scalar(tag, x, step)`` per item.

        For every cluster ``k`` and every value ``v`` of it (labelled by :func:`format_value`), under
        ``.../k`` and ``.../k/v``: ``ultho/utility`` (U, in the credits' units) and ``ultho/count`` (times
        selected and credited), and the strategy's own quantities: UCB's ``ultho/bonus`` (c*sqrt(ln i / N))
        and ``ultho/ucb`` (U / scale + bonus, the bound Eqs. 4-5 maximise); Thompson sampling's
        ``ultho/ts_mean`` (U / scale) and ``ultho/ts_std``; Exp3's ``ultho/probability`` (of the cluster, and of
        the value within its cluster). The bonus uses i of the latest selection, so right after :meth:`select`
        these are exactly the bounds that choice maximised. Also ``ultho/selected_cluster`` (index of the
        latest choice's cluster, -1 before any), ``ultho/selected_value_index``, ``ultho/selected_value``,
        ``ultho/credit_scale`` and ``ultho/last_credit`` (the latest credit, after the transform).
        """
        log_i = math.log(self._num_selections) if self._num_selections > 0 else 0.0
        out: dict[str, float] = {}
        for name, cluster_arm, value_arms in zip(self.cluster_names, self._clusters, self._values):
            levels = [([name], [cluster_arm], self._clusters),
                      ([f"{name}/{format_value(v)}" for v in self.search_space[name]], value_arms, value_arms)]
            for tags, arms, siblings in levels:
                probabilities = self._exp3_probabilities(siblings) if self.strategy == "exp3" else None
                for tag, arm in zip(tags, arms):
                    out[f"ultho/utility/{tag}"] = arm.utility
                    out[f"ultho/count/{tag}"] = float(arm.count - 1)
                    if self.strategy == "ucb":
                        bonus = arm.bonus(self.c, log_i)
                        out[f"ultho/bonus/{tag}"] = bonus
                        out[f"ultho/ucb/{tag}"] = self._scaled(arm.utility) + bonus
                    elif self.strategy == "ts":
                        out[f"ultho/ts_mean/{tag}"] = self._scaled(arm.utility)
                        out[f"ultho/ts_std/{tag}"] = arm.posterior_std()
                    elif self.strategy == "exp3":
                        out[f"ultho/probability/{tag}"] = probabilities[siblings.index(arm)]
        if self._last is None:
            out["ultho/selected_cluster"] = -1.0
            out["ultho/selected_value_index"] = -1.0
            out["ultho/selected_value"] = math.nan
        else:
            cluster, value = self._last
            out["ultho/selected_cluster"] = float(cluster)
            out["ultho/selected_value_index"] = float(value)
            out["ultho/selected_value"] = float(self.search_space[self.cluster_names[cluster]][value])
        out["ultho/credit_scale"] = self.credit_scale
        out["ultho/last_credit"] = self._last_credit
        return out

    # ------------------------------------------------------------------ persistence
    def state_dict(self) -> dict[str, Any]:
        """Everything needed to continue exactly, as JSON-serialisable builtins (a pending selection and the
        generator's state too)."""

        def arm_state(arm: _Arm) -> dict[str, Any]:
            return {"count": arm.count, "credits": list(arm.credits), "exp3_sum": arm.exp3_sum}

        version, internal, gauss_next = self._rng.getstate()
        return {
            "format": STATE_FORMAT,
            "search_space": {name: list(values) for name, values in self.search_space.items()},
            **self.options(),
            "num_selections": self._num_selections,
            "pending": list(self._pending) if self._pending is not None else None,
            "pending_before": self._pending_before,
            "pending_probabilities": list(self._pending_probabilities),
            "last": list(self._last) if self._last is not None else None,
            "last_credit": None if math.isnan(self._last_credit) else self._last_credit,
            "credit_stats": list(self._stats),
            "rng": [version, list(internal), gauss_next],
            "clusters": [arm_state(arm) for arm in self._clusters],
            "values": [[arm_state(arm) for arm in arms] for arms in self._values],
        }

    @classmethod
    def from_state_dict(cls, state: Mapping[str, Any]) -> "ULTHO":
        """A bandit rebuilt from :meth:`state_dict`; raises ValueError if the state is malformed."""
        try:
            options = {k: state[k] for k in ("strategy", "credit", "scale", "seed", "exp3_eta") if k in state}
            bandit = cls(state["search_space"], c=state["c"], window=state["window"], **options)
        except (KeyError, TypeError) as err:
            raise ValueError(f"bandit state dict is malformed: {err!r}") from None
        bandit.load_state_dict(state)
        return bandit

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restores :meth:`state_dict` output into this bandit, which must have the same space and options.

        A state of format 1 (it holds no strategy, credit or scale) is the paper's UCB with level credits, unscaled.

        Raises ValueError (and leaves this bandit unchanged) if the state does not match or is inconsistent.
        """
        try:
            self._load_checked(state)
        except (KeyError, TypeError, IndexError) as err:
            raise ValueError(f"bandit state dict is malformed: {err!r}") from None

    def _load_checked(self, state: Mapping[str, Any]) -> None:
        if state.get("format") not in (1, STATE_FORMAT):
            raise ValueError(f"bandit state format {state.get('format')!r} is not {STATE_FORMAT}")
        theirs = validate_search_space(state["search_space"])
        if list(theirs) != self.cluster_names or any(
            [format_value(v) for v in theirs[k]] != [format_value(v) for v in self.search_space[k]] for k in theirs
        ):
            raise ValueError(f"bandit state is for search space {theirs}, not {self.search_space}")
        paper = {"strategy": "ucb", "credit": "level", "scale": "none", "seed": self.seed,
                 "exp3_eta": self.exp3_eta}
        theirs_options = {"c": float(state["c"]), "window": state["window"],
                          **{k: state.get(k, default) for k, default in paper.items()}}
        if theirs_options != self.options():
            different = ", ".join(f"{k}={theirs_options[k]!r}" for k in theirs_options
                                  if theirs_options[k] != self.options()[k])
            mine = ", ".join(f"{k}={self.options()[k]!r}" for k in theirs_options
                             if theirs_options[k] != self.options()[k])
            raise ValueError(f"bandit state has {different}; this bandit {mine}")

        def arm_from(arm_state: Mapping[str, Any]) -> _Arm:
            arm = _Arm(self.window)
            credits = [float(u) for u in arm_state["credits"]]
            count = arm_state["count"]
            if not isinstance(count, int) or count < 1 or len(credits) > min(count - 1, self.window):
                raise ValueError(f"bandit state has an arm with count {count!r} and {len(credits)} credits")
            if not all(math.isfinite(u) for u in credits):
                raise ValueError("bandit state holds a non-finite credit")
            arm.credits.extend(credits)
            arm.count = count
            arm.utility = math.fsum(credits) / len(credits) if credits else 0.0
            arm.exp3_sum = float(arm_state.get("exp3_sum", 0.0))
            return arm

        clusters = [arm_from(s) for s in state["clusters"]]
        values = [[arm_from(s) for s in arms] for arms in state["values"]]
        if len(clusters) != len(self.cluster_names) or [len(v) for v in values] != [
            len(v) for v in self.search_space.values()
        ]:
            raise ValueError("bandit state has a different number of arms than its search space")
        for cluster_arm, value_arms in zip(clusters, values):
            if cluster_arm.count - 1 != sum(arm.count - 1 for arm in value_arms):
                raise ValueError("bandit state's cluster counts do not add up to its value counts")
        num_selections = state["num_selections"]
        pending = tuple(state["pending"]) if state["pending"] is not None else None
        last = tuple(state["last"]) if state["last"] is not None else None
        credited = sum(arm.count - 1 for arm in clusters)
        if num_selections != credited + (pending is not None):
            raise ValueError(f"bandit state: {num_selections} selections but {credited} credits")
        for choice in (pending, last):
            if choice is not None and not (0 <= choice[0] < len(values) and 0 <= choice[1] < len(values[choice[0]])):
                raise ValueError(f"bandit state names a selection {list(choice)} outside its search space")
        if num_selections > 0 and last is None:
            raise ValueError("bandit state has selections but no latest selection")
        before = state.get("pending_before")
        if pending is not None and self.credit_mode == "improvement" and before is None:
            raise ValueError("bandit state has a pending selection without the utility measured before it")
        if "credit_stats" in state:
            count, mean, squares = state["credit_stats"]
            stats = [int(count), float(mean), float(squares)]
        else:  # format 1 kept no statistics; they are only read with scale="running", which format 1 lacks
            stats = [credited, 0.0, 0.0]
        if stats[0] != credited:
            raise ValueError(f"bandit state's credit statistics count {stats[0]} credits, not {credited}")
        rng = random.Random()
        if "rng" in state:
            version, internal, gauss_next = state["rng"]
            rng.setstate((version, tuple(internal), gauss_next))
        else:
            rng.seed(self.seed)
        last_credit = state.get("last_credit")
        self._clusters, self._values = clusters, values
        self._num_selections = num_selections
        self._pending, self._last = pending, last
        self._pending_before = None if before is None else float(before)
        self._pending_probabilities = tuple(state.get("pending_probabilities", (1.0, 1.0)))
        self._last_credit = math.nan if last_credit is None else float(last_credit)
        self._stats = stats
        self._rng = rng


def parse_value(token: str) -> Number:
    """``"128"`` -> 128, ``"1e-3"`` -> 0.001; raises ValueError for anything but a finite number."""
    text = token.strip()
    try:
        return int(text)
    except ValueError:
        pass
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{token!r} is not a number") from None
    if not math.isfinite(value):
        raise ValueError(f"{token!r} is not a finite number")
    return value


def parse_clusters(
    items: Sequence[str],
    defaults: Mapping[str, Sequence[Number]],
    allowed: Sequence[str] | None = None,
) -> SearchSpace:
    """Turns CLI items into a search space, keeping their order.

    ``"learning_rate"`` takes the benchmark's default values from ``defaults``; ``"vf_coef=0.25,0.5,1.0"``
    sets the values explicitly. ``allowed`` lists the setting names an explicit item may use (default: the
    names in ``defaults``).

    Raises:
        ValueError: no items, a malformed item, an unknown or repeated cluster name, or bad values; the
            message names the offending item.
    """
    allowed_names = list(defaults) if allowed is None else list(allowed)
    space: dict[str, list[Number]] = {}
    for item in items:
        name, sep, rest = item.partition("=")
        name = name.strip()
        if not name:
            raise ValueError(f"malformed cluster item {item!r}: expected NAME or NAME=V1,V2,...")
        if name not in allowed_names:
            raise ValueError(f"unknown cluster {name!r} in {item!r}; known: {', '.join(allowed_names)}")
        if name in space:
            raise ValueError(f"cluster {name!r} is given twice")
        if not sep:
            if name not in defaults:
                raise ValueError(f"cluster {name!r} has no default values here; give them as {name}=V1,V2,...")
            space[name] = list(defaults[name])
            continue
        tokens = rest.split(",")
        if not rest.strip() or any(not t.strip() for t in tokens):
            raise ValueError(f"malformed cluster item {item!r}: expected {name}=V1,V2,...")
        try:
            space[name] = [parse_value(t) for t in tokens]
        except ValueError as err:
            raise ValueError(f"cluster item {item!r}: {err}") from None
    return validate_search_space(space)
