"""The ULTHO hierarchical UCB bandit (Yuan et al., ICCV 2025, Algorithm 1, Eqs. 4-7).

A search space is an ordered mapping ``cluster name -> candidate values``; the cluster name is the PPO
setting the value overrides (``args.<name> = value``). Every iteration a training loop calls
:meth:`ULTHO.select` once and, after the update that used the chosen value, credits it with
:meth:`ULTHO.update`. Selections and credits strictly alternate.

Conventions this module fixes (see ``ULTHO_SPEC.md``, "The bandit"):

* every cluster and every value starts with N = 1 and U = 0 and keeps a FIFO window of its last W credits;
* selection number i (1, 2, 3, ...) uses ``ln(i)`` in the bonus at *both* levels (Eqs. 4 and 5);
* ties go to the earliest cluster / value, so the first selection is the first cluster's first value;
* U is the mean of the credits in the window (Eq. 6), of those present while fewer than W.

Pure Python: one ``select()`` + ``update()`` pair over 4 clusters x 3 values costs a few microseconds
(``benchmarks/bench_bandit.py``).
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any, Mapping, Sequence

Number = int | float
SearchSpace = dict[str, list[Number]]

STATE_FORMAT = 1


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
    """One arm (a cluster or a value): its count N and the FIFO window behind its utility U."""

    __slots__ = ("count", "credits", "utility")

    def __init__(self, window: int) -> None:
        self.count = 1  # N starts at 1 (Algorithm 1, line 3)
        self.credits: deque[float] = deque(maxlen=window)
        self.utility = 0.0  # U starts at 0

    def credit(self, utility: float) -> None:
        """Eq. 6: push the credit into the window, U = window mean, N += 1."""
        self.credits.append(utility)
        self.utility = math.fsum(self.credits) / len(self.credits)
        self.count += 1

    def bonus(self, c: float, log_i: float) -> float:
        """The exploration term ``c * sqrt(ln(i) / N)`` of Eqs. 4 and 5."""
        return c * math.sqrt(log_i / self.count)


def _argmax_ucb(arms: Sequence[_Arm], c: float, log_i: float) -> int:
    """Index of the arm with the highest U + bonus; the strict ``>`` gives ties to the earliest arm."""
    best, best_bound = 0, -math.inf
    for index, arm in enumerate(arms):
        bound = arm.utility + arm.bonus(c, log_i)
        if bound > best_bound:
            best, best_bound = index, bound
    return best


class ULTHO:
    """Hierarchical UCB over clusters of hyperparameter values (Algorithm 1).

    Args:
        search_space: ordered ``{cluster name: [candidate values]}``; names are the settings to override.
        c: exploration coefficient of Eqs. 4 and 5 (finite, >= 0). The paper's grid is {1, 5}.
        window: W, the number of most recent credits averaged into a utility (Eq. 6). Paper: {10, 50, 100}.

    Raises:
        ValueError: an invalid search space, c or window.
    """

    def __init__(self, search_space: Mapping[str, Sequence[Any]], c: float = 5.0, window: int = 10) -> None:
        self.search_space = validate_search_space(search_space)
        if isinstance(c, bool) or not isinstance(c, (int, float)) or not math.isfinite(c) or c < 0:
            raise ValueError(f"exploration coefficient c={c!r} must be a finite number >= 0")
        if isinstance(window, bool) or not isinstance(window, int) or window < 1:
            raise ValueError(f"window={window!r} must be an integer >= 1")
        self.c = float(c)
        self.window = window
        self.cluster_names = list(self.search_space)
        self._clusters = [_Arm(window) for _ in self.cluster_names]
        self._values = [[_Arm(window) for _ in vals] for vals in self.search_space.values()]
        self._num_selections = 0
        self._pending: tuple[int, int] | None = None
        self._last: tuple[int, int] | None = None

    # ------------------------------------------------------------------ the algorithm
    def select(self) -> tuple[str, Number]:
        """Selection number i: a cluster by Eq. 4, then a value inside it by Eq. 5 (same global i).

        Returns ``(cluster name, value)``. The choice stays pending until :meth:`update` credits it.

        Raises:
            RuntimeError: the previous selection has not been credited yet.
        """
        if self._pending is not None:
            raise RuntimeError("select() called twice without update(): credit the pending selection first")
        self._num_selections += 1
        log_i = math.log(self._num_selections)
        cluster = _argmax_ucb(self._clusters, self.c, log_i)
        value = _argmax_ucb(self._values[cluster], self.c, log_i)
        self._pending = self._last = (cluster, value)
        name = self.cluster_names[cluster]
        return name, self.search_space[name][value]

    def update(self, utility: float) -> None:
        """Credits the pending selection with ``utility`` (Eq. 6), for its cluster and its value.

        The paper's utility is the mean critic value of the updated policy, V-bar in Eq. 6.

        Raises:
            RuntimeError: no selection is pending.
            ValueError: ``utility`` is not a finite number (nothing is credited then).
        """
        if self._pending is None:
            raise RuntimeError("update() without a pending selection: call select() first")
        if hasattr(utility, "item") and not isinstance(utility, (int, float)):
            utility = utility.item()
        if isinstance(utility, bool) or not isinstance(utility, (int, float)) or not math.isfinite(utility):
            raise ValueError(f"utility {utility!r} is not a finite number; the selection stays uncredited")
        cluster, value = self._pending
        self._clusters[cluster].credit(float(utility))
        self._values[cluster][value].credit(float(utility))
        self._pending = None

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

    def scalars(self) -> dict[str, float]:
        """A flat ``{tag: float}`` for TensorBoard: one ``writer.add_scalar(tag, x, step)`` per item.

        For every cluster ``k`` and every value ``v`` of it (labelled by :func:`format_value`):
        ``ultho/utility/k`` (U), ``ultho/bonus/k`` (c*sqrt(ln i / N)), ``ultho/ucb/k`` (U + bonus, the bound
        Eq. 4 maximises), ``ultho/count/k`` (times selected and credited), and the same four under
        ``.../k/v`` for the values (Eq. 5). The bonus uses i of the latest selection, so right after
        :meth:`select` these are exactly the bounds that choice maximised. Also
        ``ultho/selected_cluster`` (index of the latest choice's cluster, -1 before any),
        ``ultho/selected_value_index`` and ``ultho/selected_value``.
        """
        log_i = math.log(self._num_selections) if self._num_selections > 0 else 0.0
        out: dict[str, float] = {}
        for name, cluster_arm, value_arms in zip(self.cluster_names, self._clusters, self._values):
            arms = [(name, cluster_arm)]
            arms += [(f"{name}/{format_value(v)}", a) for v, a in zip(self.search_space[name], value_arms)]
            for tag, arm in arms:
                bonus = arm.bonus(self.c, log_i)
                out[f"ultho/utility/{tag}"] = arm.utility
                out[f"ultho/bonus/{tag}"] = bonus
                out[f"ultho/ucb/{tag}"] = arm.utility + bonus
                out[f"ultho/count/{tag}"] = float(arm.count - 1)
        if self._last is None:
            out["ultho/selected_cluster"] = -1.0
            out["ultho/selected_value_index"] = -1.0
            out["ultho/selected_value"] = math.nan
        else:
            cluster, value = self._last
            out["ultho/selected_cluster"] = float(cluster)
            out["ultho/selected_value_index"] = float(value)
            out["ultho/selected_value"] = float(self.search_space[self.cluster_names[cluster]][value])
        return out

    # ------------------------------------------------------------------ persistence
    def state_dict(self) -> dict[str, Any]:
        """Everything needed to continue exactly, as JSON-serialisable builtins (a pending selection too)."""

        def arm_state(arm: _Arm) -> dict[str, Any]:
            return {"count": arm.count, "credits": list(arm.credits)}

        return {
            "format": STATE_FORMAT,
            "search_space": {name: list(values) for name, values in self.search_space.items()},
            "c": self.c,
            "window": self.window,
            "num_selections": self._num_selections,
            "pending": list(self._pending) if self._pending is not None else None,
            "last": list(self._last) if self._last is not None else None,
            "clusters": [arm_state(arm) for arm in self._clusters],
            "values": [[arm_state(arm) for arm in arms] for arms in self._values],
        }

    @classmethod
    def from_state_dict(cls, state: Mapping[str, Any]) -> "ULTHO":
        """A bandit rebuilt from :meth:`state_dict`; raises ValueError if the state is malformed."""
        try:
            bandit = cls(state["search_space"], c=state["c"], window=state["window"])
        except (KeyError, TypeError) as err:
            raise ValueError(f"bandit state dict is malformed: {err!r}") from None
        bandit.load_state_dict(state)
        return bandit

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restores :meth:`state_dict` output into this bandit, which must have the same space, c and W.

        Raises ValueError (and leaves this bandit unchanged) if the state does not match or is inconsistent.
        """
        try:
            self._load_checked(state)
        except (KeyError, TypeError, IndexError) as err:
            raise ValueError(f"bandit state dict is malformed: {err!r}") from None

    def _load_checked(self, state: Mapping[str, Any]) -> None:
        if state.get("format") != STATE_FORMAT:
            raise ValueError(f"bandit state format {state.get('format')!r} is not {STATE_FORMAT}")
        theirs = validate_search_space(state["search_space"])
        if list(theirs) != self.cluster_names or any(
            [format_value(v) for v in theirs[k]] != [format_value(v) for v in self.search_space[k]] for k in theirs
        ):
            raise ValueError(f"bandit state is for search space {theirs}, not {self.search_space}")
        if float(state["c"]) != self.c or state["window"] != self.window:
            raise ValueError(
                f"bandit state has c={state['c']}, window={state['window']}; this bandit c={self.c}, "
                f"window={self.window}"
            )

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
        self._clusters, self._values = clusters, values
        self._num_selections = num_selections
        self._pending, self._last = pending, last


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
