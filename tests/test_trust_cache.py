"""The qualification cache can be neither fooled nor poisoned (issue 39, docs/devices.md).

* the test session writes its verdicts into a cache folder of its own, never the user's;
* a check that times out (or is killed from outside) is *not checked yet*: never cached, never
  a failure; a run walks the next narrower width already qualified and says so in one line;
* a hand-edited or damaged entry is not believed: types and ranges, the key, and a SHA-256;
* a cache folder that cannot be written keeps Intel's runtime registered (a private folder),
  so that the devices keep their numbers, and says so once;
* ``warpe-cl devices`` lists every kernel combination's cached verdict, ``--all`` checks the
  rest.

No test here runs a real qualification: the child process is replaced (``subprocess.run`` or
``run_child``) and the entries are written by hand into a temporary cache folder.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from warpe_cl import device as devmod
from warpe_cl import drivers, qualify, report
from warpe_cl.errors import WarpeWarning

#: a CPU whose driver prefers scalar code (Intel's runtime): double-precision chain 8, 4, 1
CPU = devmod.DeviceInfo(0, 0, "Fake OpenCL", "OpenCL 3.0 fake", "Fake CPU", "cpu", "1.0", 2,
                        True)
WEIGHTED_DOUBLE = qualify.Combo("slab", "double", True)
#: the 1-min load average per core of a busy machine (a timeout then is no verdict)
BUSY = 3.0


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """A cache folder of the test's own, as the default of every VerdictCache."""
    monkeypatch.setenv("WARPE_CL_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("WARPE_CL_LANES", raising=False)
    monkeypatch.setattr(qualify, "_warned_invalid", set(), raising=False)
    monkeypatch.setattr(qualify, "load_per_core", lambda: BUSY, raising=False)   # busy
    qualify._qualifiers.clear()
    yield qualify.VerdictCache(tmp_path)
    qualify._qualifiers.clear()


def passed(speed=None) -> dict:
    """A passing verdict as a check writes it."""
    return {"passed": True, "reason": None, "events_per_s": speed, "seconds": 1.5,
            "date": "2026-11-26T10:00:00", "child_wall_s": 2.0}


def failed(reason="slab_fresnel: only 0.0% of the rays follow the reference's history") -> dict:
    return {"passed": False, "reason": reason, "events_per_s": None, "seconds": 1.5,
            "date": "2026-11-26T10:00:00", "child_wall_s": 2.0}


def key(lanes, combo=WEIGHTED_DOUBLE, info=CPU):
    return qualify.combo_key(info, lanes, combo)


class FakeChild:
    """``subprocess.run`` of the check's child: per lane width, a timeout, a signal, or the
    verdicts it prints; every call recorded as its lane width."""

    def __init__(self, monkeypatch, outcomes):
        self.outcomes = outcomes
        self.calls = []
        monkeypatch.setattr(qualify.subprocess, "run", self)

    def __call__(self, cmd, **kw):
        lanes = int(cmd[cmd.index("--lanes") + 1])
        labels = cmd[cmd.index("--combos") + 1].split(",")
        self.calls.append(lanes)
        outcome = self.outcomes[lanes]
        if outcome == "timeout":
            raise subprocess.TimeoutExpired(cmd, kw.get("timeout"))
        if isinstance(outcome, int):                      # killed by this signal
            return subprocess.CompletedProcess(cmd, -outcome, "", "")
        out = qualify.MARK + json.dumps({label: outcome for label in labels})
        return subprocess.CompletedProcess(cmd, 0, out + "\n", "")


def no_child(monkeypatch):
    def refuse(*a, **k):
        raise AssertionError("nothing may be checked here")
    monkeypatch.setattr(qualify, "run_child", refuse)


# --------------------------------------------------------------------------------------------
# 1. the test session has its own cache folder

def test_the_test_session_has_its_own_cache_folder(engine, monkeypatch):
    """conftest.py points $WARPE_CL_CACHE_DIR at a folder of the session before warpe-cl reads
    it: verdicts go there, children inherit it, and Intel's runtime is still registered (in
    that folder), so the session's engine still has its device."""
    session = drivers.cache_dir()
    with monkeypatch.context() as m:
        m.delenv("WARPE_CL_CACHE_DIR", raising=False)
        users = drivers.cache_dir()
    assert session != users and users.resolve() not in session.resolve().parents
    assert qualify.VerdictCache().folder == session
    child = subprocess.run([sys.executable, "-c",
                            "from warpe_cl.drivers import cache_dir; print(cache_dir())"],
                           capture_output=True, text=True, timeout=120)
    assert child.stdout.strip() == str(session), child.stderr
    # the session's verdicts are in its folder (the engine fixture qualified its device)
    assert (session / "qualification.json").is_file()
    if drivers.pip_driver_libraries() and os.environ.get("WARPE_CL_PIP_DRIVERS", "1") != "0":
        icd = Path(os.environ["OCL_ICD_VENDORS"])
        assert icd.parent == session / "icd"
        assert any("libintelocl" in p.read_text() for p in icd.iterdir())
        first = devmod.list_devices()[0][0]
        assert first.spec == "0:0" and first.platform.startswith("Intel")


# --------------------------------------------------------------------------------------------
# 2. a timed-out check is not checked yet

def test_a_timed_out_check_is_cached_as_not_checked_yet_and_not_waited_for_again(cache,
                                                                                 monkeypatch):
    """8 lanes of double-precision weighted slab times out on a loaded machine; 4 lanes passed
    before: the run walks 4 lanes with one warning line that says 8 was not checked yet. The
    timeout is cached as *not checked yet* (its date, a count of 1; no failure), so that the
    next process (a sweep worker, `devices`) walks 4 lanes without waiting for it again."""
    assert qualify.Qualifier(CPU).lane_chain("double") == (8, 4, 1)
    cache.put([(key(4), passed())])
    child = FakeChild(monkeypatch, {8: "timeout"})
    q = qualify.Qualifier(CPU, cache=cache, say=lambda m: None)
    with pytest.warns(WarpeWarning) as caught:
        lanes, failures = q.best_lanes(WEIGHTED_DOUBLE)
    assert (lanes, failures, child.calls) == (4, [], [8])
    messages = [str(w.message) for w in caught if issubclass(w.category, WarpeWarning)]
    assert len(messages) == 1 and "\n" not in messages[0]
    assert "not checked yet" in messages[0] and "walking 4 lanes" in messages[0]
    assert "failed" not in messages[0]
    stored = cache.get(key(8))
    assert qualify.is_unchecked(stored) and stored["unfinished"] == 1 and stored["date"]
    assert not stored["passed"] and stored["load_per_core"] == BUSY
    # the same process and the next one do not wait again (within a day)
    with pytest.warns(WarpeWarning, match="not checked yet"):
        assert q.best_lanes(WEIGHTED_DOUBLE)[0] == 4 and child.calls == [8]
    again = qualify.Qualifier(CPU, cache=qualify.VerdictCache(cache.folder))
    with pytest.warns(WarpeWarning, match="not checked yet"):
        assert again.best_lanes(WEIGHTED_DOUBLE) == (4, []) and child.calls == [8]


def _age(cache, lookup, seconds):
    """Date the stored entry of ``lookup`` ``seconds`` back (hash recomputed)."""
    when = time.strftime(qualify.DATE_FORMAT, time.localtime(time.time() - seconds))
    _edit(cache, lookup, date=when)


def test_an_old_timeout_is_checked_again_and_a_second_one_is_a_failure(cache, monkeypatch):
    """A *not checked yet* entry older than a day is checked again: passing, it is a pass;
    timing out again (the same key), it is a failure, cached, with the reason."""
    cache.put([(key(4), passed())])
    child = FakeChild(monkeypatch, {8: "timeout"})
    q = qualify.Qualifier(CPU, cache=cache, say=lambda m: None)
    with pytest.warns(WarpeWarning):
        q.best_lanes(WEIGHTED_DOUBLE)
    _age(cache, key(8), qualify.UNCHECKED_TTL_S + 60)
    q = qualify.Qualifier(CPU, cache=qualify.VerdictCache(cache.folder), say=lambda m: None)
    with pytest.warns(WarpeWarning, match="failed qualification at 8 lanes"):
        assert q.best_lanes(WEIGHTED_DOUBLE)[0] == 4
    assert child.calls == [8, 8]
    stored = cache.get(key(8))
    assert not stored["passed"] and not qualify.is_unchecked(stored)
    assert "no verdict twice at 8 lanes" in stored["reason"] and "--requalify" in stored["reason"]
    # a failure is not checked again, however old
    q = qualify.Qualifier(CPU, cache=qualify.VerdictCache(cache.folder), say=lambda m: None)
    with pytest.warns(WarpeWarning, match="failed"):
        q.best_lanes(WEIGHTED_DOUBLE)
    assert child.calls == [8, 8]
    # --requalify forgets it: checked again
    cache.clear()
    child.outcomes[8] = passed()
    q = qualify.Qualifier(CPU, cache=qualify.VerdictCache(cache.folder), say=lambda m: None)
    assert q.best_lanes(WEIGHTED_DOUBLE) == (8, []) and child.calls == [8, 8, 8]


def test_an_old_timeout_that_now_passes_is_a_pass(cache, monkeypatch):
    FakeChild(monkeypatch, {8: "timeout", 4: passed()})
    q = qualify.Qualifier(CPU, cache=cache, say=lambda m: None)
    with pytest.warns(WarpeWarning):
        q.best_lanes(WEIGHTED_DOUBLE)
    _age(cache, key(8), 2 * qualify.UNCHECKED_TTL_S)
    child = FakeChild(monkeypatch, {8: passed()})
    q = qualify.Qualifier(CPU, cache=qualify.VerdictCache(cache.folder), say=lambda m: None)
    assert q.best_lanes(WEIGHTED_DOUBLE) == (8, []) and child.calls == [8]
    assert cache.get(key(8))["passed"]


def test_a_timeout_on_a_machine_that_was_not_busy_is_a_failure(cache, monkeypatch):
    """Load average per core below 1 when the check timed out: the driver hangs (PoCL 3.0 at
    16 lanes on Zen 4): a failure at once, cached, so no later process waits for it."""
    monkeypatch.setattr(qualify, "load_per_core", lambda: 0.25)
    cache.put([(key(4), passed())])
    child = FakeChild(monkeypatch, {8: "timeout"})
    q = qualify.Qualifier(CPU, cache=cache, say=lambda m: None)
    with pytest.warns(WarpeWarning, match="failed qualification at 8 lanes"):
        assert q.best_lanes(WEIGHTED_DOUBLE) == (4, [(8, cache.get(key(8))["reason"])])
    stored = cache.get(key(8))
    assert not qualify.is_unchecked(stored) and "not busy (load 0.25 per core)" in stored["reason"]
    q = qualify.Qualifier(CPU, cache=qualify.VerdictCache(cache.folder), say=lambda m: None)
    with pytest.warns(WarpeWarning, match="failed"):
        q.best_lanes(WEIGHTED_DOUBLE)
    assert child.calls == [8]


def test_a_kill_from_outside_is_cached_and_a_second_one_is_a_failure(cache, monkeypatch):
    """The OOM killer ends the child (its own compiler's memory): not checked yet, cached, so
    the next process does not trigger it again; the second kill at the key is a failure."""
    monkeypatch.setattr(qualify, "load_per_core", lambda: 0.1)   # no bearing on a kill
    child = FakeChild(monkeypatch, {8: int(signal.SIGKILL)})
    q = qualify.Qualifier(CPU, cache=cache, say=lambda m: None)
    assert qualify.is_unchecked(q.verdicts(8, [WEIGHTED_DOUBLE])[WEIGHTED_DOUBLE])
    q = qualify.Qualifier(CPU, cache=qualify.VerdictCache(cache.folder), say=lambda m: None)
    assert qualify.is_unchecked(q.verdicts(8, [WEIGHTED_DOUBLE])[WEIGHTED_DOUBLE])
    assert child.calls == [8]
    _age(cache, key(8), qualify.UNCHECKED_TTL_S + 1)
    q = qualify.Qualifier(CPU, cache=qualify.VerdictCache(cache.folder), say=lambda m: None)
    entry = q.verdicts(8, [WEIGHTED_DOUBLE])[WEIGHTED_DOUBLE]
    assert child.calls == [8, 8] and not entry["passed"] and not qualify.is_unchecked(entry)
    assert "SIGKILL" in entry["reason"] and cache.get(key(8))["reason"] == entry["reason"]


def test_a_timeout_with_nothing_qualified_below_checks_the_narrower_widths(cache, monkeypatch):
    """Nothing cached: after 8 lanes time out, 4 lanes is checked (and cached); when every
    width times out, nothing is usable, nothing is cached, and the reason says not checked."""
    child = FakeChild(monkeypatch, {8: "timeout", 4: passed()})
    q = qualify.Qualifier(CPU, cache=cache, say=lambda m: None)
    with pytest.warns(WarpeWarning, match="not checked yet.*walking 4 lanes"):
        assert q.best_lanes(WEIGHTED_DOUBLE) == (4, [])
    assert child.calls == [8, 4] and cache.get(key(4))["passed"]
    assert qualify.is_unchecked(cache.get(key(8)))

    analog = qualify.Combo("granular", "double", False)
    child = FakeChild(monkeypatch, dict.fromkeys((8, 4, 1), "timeout"))
    q = qualify.Qualifier(CPU, cache=cache, say=lambda m: None)
    lanes, failures = q.best_lanes(analog)
    assert lanes is None and [w for w, _ in failures] == [8, 4, 1]
    assert all(r.startswith("not checked yet") for _, r in failures)
    assert all(qualify.is_unchecked(cache.get(key(w, analog))) for w in (8, 4, 1))


@pytest.mark.parametrize("sig, cached", [(signal.SIGKILL, False), (signal.SIGTERM, False),
                                         (signal.SIGINT, False), (signal.SIGABRT, True),
                                         (signal.SIGSEGV, True)])
def test_a_child_killed_from_outside_is_not_a_verdict(cache, monkeypatch, sig, cached):
    """SIGKILL (the OOM killer), SIGTERM, SIGINT come from outside: not checked yet (cached as
    such). SIGABRT and SIGSEGV are the driver's own: a failure, cached."""
    FakeChild(monkeypatch, {8: int(sig)})
    q = qualify.Qualifier(CPU, cache=cache, say=lambda m: None)
    entry = q.verdicts(8, [WEIGHTED_DOUBLE])[WEIGHTED_DOUBLE]
    assert not entry["passed"] and qualify.is_unchecked(entry) == (not cached)
    assert signal.Signals(sig).name in entry["reason"]
    assert qualify.is_unchecked(cache.get(key(8))) == (not cached)


def test_devices_says_not_checked_yet_instead_of_qualified(cache, monkeypatch):
    """The ranking kernel's widest width (16) times out, 8 passed before with its speed: the
    device is usable at 8 lanes, and `warpe-cl devices` says 16 lanes are not checked yet."""
    rank = qualify.RANK_COMBO
    cache.put([(key(8, rank), passed(speed=1.2e8))])
    FakeChild(monkeypatch, {16: "timeout"})
    status = qualify.qualification(CPU, say=lambda m: None)
    assert status.usable and status.lanes == 8 and status.events_per_s == 1.2e8
    assert status.failures == () and [w for w, _ in status.unchecked] == [16]
    lines = report.device_status_lines(None, status)
    assert lines[0].strip().startswith("qualified: 8 lanes")
    assert any("not checked yet at 16 lanes" in ln and "did not finish" in ln for ln in lines)
    assert not any("failed" in ln for ln in lines)


# --------------------------------------------------------------------------------------------
# 3. a hand-edited entry is not believed

def _edit(cache, lookup, rehash=True, stored_key=None, **changes):
    """Change the stored entry of ``lookup`` by hand; ``rehash``: recompute its sha256 as a
    careful forger would (so that only the validation of its fields can catch it)."""
    data = cache._read()
    kid = qualify._key_id(lookup)
    entry = {**data[kid], **changes}
    if stored_key is not None:
        entry["key"] = stored_key
    if rehash:
        try:
            entry["sha256"] = qualify.entry_hash(entry, entry["key"])
        except ValueError:              # inf or NaN: no JSON hash can be made of them
            pass
    data[kid] = entry
    cache.path.write_text(json.dumps(data))


@pytest.mark.parametrize("changes", [
    {"passed": "false"}, {"passed": 1}, {"passed": None},
    {"events_per_s": 1e20}, {"events_per_s": -5.0}, {"events_per_s": float("inf")},
    {"events_per_s": "fast"}, {"seconds": -1.0}, {"seconds": float("nan")},
    {"reason": 42}, {"date": 20261126}, {"trusted": True},
])
def test_a_hand_edited_entry_is_not_believed(cache, changes):
    """Wrong types and ranges are refused even where the sha256 was recomputed."""
    k = key(4, qualify.RANK_COMBO)
    cache.put([(k, passed(speed=1e8))])
    assert cache.get(k)["passed"] is True
    _edit(cache, k, **changes)
    with pytest.warns(WarpeWarning, match="not valid"):
        assert cache.get(k) is None


def test_an_entry_whose_hash_or_key_does_not_match_is_not_believed(cache):
    """A verdict turned from failed to passed by hand (its hash left as it was), an entry
    copied under another key's id, and an entry without its hash: ignored (said once)."""
    k4, k8 = key(4), key(8)
    cache.put([(k4, failed()), (k8, passed())])
    _edit(cache, k4, rehash=False, passed=True, reason=None)
    with pytest.warns(WarpeWarning) as caught:
        assert cache.get(k4) is None
        _edit(cache, k8, stored_key=k4)          # 4 lanes' key, rehashed, under 8's id
        assert cache.get(k8) is None
    assert len([w for w in caught if issubclass(w.category, WarpeWarning)]) == 1
    assert "sha256" in str(caught[0].message)
    data = cache._read()
    data[qualify._key_id(k4)] = {**failed(), "key": k4}      # no hash: an older warpe-cl's
    cache.path.write_text(json.dumps(data))
    assert cache.get(k4) is None


def test_a_forged_speed_does_not_win_auto(cache, monkeypatch):
    """events_per_s: 1e20 written into the cache of the ranking kernel (hash recomputed) is
    not believed: the device is measured again and ranked by what it really walks."""
    k = key(16, qualify.RANK_COMBO)
    cache.put([(k, passed(speed=1e8))])
    _edit(cache, k, events_per_s=1e20)
    child = FakeChild(monkeypatch, {16: passed(speed=1.1e8)})
    with pytest.warns(WarpeWarning, match="events_per_s 1e\\+20"):
        status = qualify.qualification(CPU, say=lambda m: None)
    assert child.calls == [16] and status.events_per_s == 1.1e8
    assert cache.get(k)["events_per_s"] == 1.1e8


# --------------------------------------------------------------------------------------------
# 4. a cache folder that cannot be written

# the verdict cache first: where no pip driver is registered, it is what finds the folder
# unwritable and hands the private one to $WARPE_CL_CACHE_DIR
LISTING = """
import json, os
from warpe_cl.device import list_devices
from warpe_cl.qualify import VerdictCache
devices = [[i.spec, i.platform, i.device] for i, _ in list_devices()]
verdicts = str(VerdictCache().folder)
print(json.dumps({"devices": devices, "cache": os.environ.get("WARPE_CL_CACHE_DIR"),
                  "verdicts": verdicts, "icd": os.environ.get("OCL_ICD_VENDORS")}))
"""


def _listing(cache_dir: Path, pip_drivers: str = "1") -> tuple:
    env = {k: v for k, v in os.environ.items()
           if k not in ("OCL_ICD_VENDORS", "WARPE_CL_TEST_CACHE_DIR")}
    env["WARPE_CL_CACHE_DIR"] = str(cache_dir)
    env["WARPE_CL_PIP_DRIVERS"] = pip_drivers
    out = subprocess.run([sys.executable, "-c", LISTING], capture_output=True, text=True,
                         env=env, timeout=300)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.splitlines()[-1]), out.stderr


@pytest.mark.parametrize("pip_drivers", ["1", "0"])
def test_an_unwritable_cache_folder_keeps_the_device_numbers(tmp_path, pip_drivers):
    """$WARPE_CL_CACHE_DIR under a regular file (root ignores chmod): the devices are the
    same, in the same order, as with a writable folder -- Intel's runtime registered from a
    private folder -- with one warning line naming both folders and the cost; the private
    folder is gone when the process ends. Also with no pip driver to register
    ($WARPE_CL_PIP_DRIVERS=0, as on an Arm machine or a GPU machine without intel-opencl-rt,
    where the check failed: the verdict cache made the private folder after the listing had
    read the variable)."""
    good, good_err = _listing(tmp_path / "writable", pip_drivers)
    (tmp_path / "a_file").write_text("not a folder")
    bad, bad_err = _listing(tmp_path / "a_file" / "cache", pip_drivers)
    assert bad["devices"] == good["devices"] and bad["devices"]
    private = Path(bad["cache"])
    assert private != tmp_path / "a_file" / "cache" and bad["verdicts"] == str(private)
    if bad["icd"]:
        assert Path(bad["icd"]).parent == private / "icd"
    warned = [ln for ln in bad_err.splitlines() if "cannot be written" in ln]
    assert len(warned) == 1, bad_err
    assert str(tmp_path / "a_file" / "cache") in warned[0] and str(private) in warned[0]
    assert "no qualification verdict is kept" in warned[0]
    assert "cannot be written" not in good_err
    assert not private.exists()


# --------------------------------------------------------------------------------------------
# 5. `warpe-cl devices` shows every kernel combination

def test_devices_lists_every_cached_combination_without_checking(cache, monkeypatch, capsys):
    """Plain `devices` shows, for every kernel combination, what the cache knows -- qualified
    width and the failures above it, not checked yet -- and checks nothing."""
    from warpe_cl import cli
    granular = qualify.Combo("granular", "single", False)
    cache.put([(key(4), passed()), (key(8), failed()),
               (key(16, granular), failed("the driver's process was killed by SIGABRT")),
               (key(8, granular), passed())])
    no_child(monkeypatch)
    cli._print_all_verdicts(CPU)
    lines = capsys.readouterr().out.splitlines()
    combos = qualify.all_combos(CPU.fp64)
    assert len(lines) == len(combos)
    by_label = {ln.split()[0]: ln for ln in lines}
    assert set(by_label) == {c.label for c in combos}
    assert "4 lanes, qualified; failed at 8: slab_fresnel" in by_label["slab:double:weighted"]
    assert "8 lanes, qualified; failed at 16: the driver's process was killed by SIGABRT" \
        in by_label["granular:single:analog"]
    assert by_label["slab:single:weighted"].split(None, 1)[1] == "not checked yet"


def test_devices_all_checks_the_combinations_not_checked_yet(cache, monkeypatch, capsys):
    """`devices --all` checks what is not cached (one child per width here), and prints each
    combination's verdict; the cached ones are not checked again."""
    from warpe_cl import cli
    gpu = devmod.DeviceInfo(0, 0, "Fake OpenCL", "OpenCL 3.0 fake", "Fake GPU", "gpu", "1.0",
                            8, False)
    cache.put([(key(1, qualify.RANK_COMBO, gpu), passed(speed=1e9))])
    child = FakeChild(monkeypatch, {1: passed()})
    cli._print_all_verdicts(gpu, check=True)
    lines = capsys.readouterr().out.splitlines()
    combos = qualify.all_combos(False)
    assert len(lines) == len(combos) and all("1 lanes, qualified" in ln for ln in lines)
    assert child.calls == [1] * (len(combos) - 1)



# --------------------------------------------------------------------------------------------
# 6. what a run says about widths not checked yet

def _engine(q):
    """An Engine with only what ``lanes_for`` reads (no OpenCL)."""
    from warpe_cl.engine import Engine
    eng = Engine.__new__(Engine)
    eng.info, eng.choose_lanes = CPU, qualify.LaneChooser(q)
    return eng


def test_an_explicit_width_not_checked_yet_says_so(cache, monkeypatch):
    """WARPE_CL_LANES=8 whose check timed out: a DeviceError that says *not checked yet*
    (what to do), never "failed qualification"."""
    FakeChild(monkeypatch, {8: "timeout"})
    eng = _engine(qualify.Qualifier(CPU, cache=cache, say=lambda m: None))
    with pytest.raises(devmod.DeviceError) as err:
        eng.lanes_for("slab", "double", True, lanes=8)
    text = str(err.value)
    assert "not checked yet: the check timed out" in text and "failed" not in text
    assert "--requalify" in text and "WARPE_CL_LANES" in text and "\n" not in text


def test_failures_and_widths_not_checked_yet_make_one_warning_line(cache, monkeypatch):
    """8 lanes failed (cached), 4 lanes times out, 1 lane passed: one warning line names
    both, and the run walks 1 lane."""
    cache.put([(key(8), failed()), (key(1), passed())])
    FakeChild(monkeypatch, {4: "timeout"})
    eng = _engine(qualify.Qualifier(CPU, cache=cache, say=lambda m: None))
    with pytest.warns(WarpeWarning) as caught:
        assert eng.lanes_for("slab", "double", True) == 1
    lines = [str(w.message) for w in caught if issubclass(w.category, WarpeWarning)]
    assert len(lines) == 1, lines
    assert "failed qualification at 8 lanes" in lines[0]
    assert "not checked yet at 4 lanes" in lines[0] and "walking 1 lanes" in lines[0]


def test_a_usable_qualification_is_made_of_a_passed_entry(cache, monkeypatch):
    """The ranking kernel passed at 8 lanes without its speed (a run that did not measure);
    16 lanes time out, and measuring 8 again times out too: the device is usable at 8 lanes
    from the passed verdict (no speed), which stays passed, in the cache and in the process."""
    rank = qualify.RANK_COMBO
    cache.put([(key(8, rank), passed(speed=None))])
    child = FakeChild(monkeypatch, {16: "timeout", 8: "timeout"})
    status = qualify.qualification(CPU, say=lambda m: None)
    assert child.calls == [16, 8]
    assert status.usable and status.lanes == 8 and status.events_per_s is None
    q = qualify.qualifier_for(CPU)
    assert q.known(8, rank)["passed"] and cache.get(key(8, rank))["passed"]


@pytest.mark.parametrize("how", ["home", "env"])
def test_the_test_cache_may_not_be_the_users_cache(tmp_path, how):
    """$WARPE_CL_TEST_CACHE_DIR naming the user's own cache folder (~/.cache/warpe-cl, or the
    user's $WARPE_CL_CACHE_DIR) stops the session with one line, before any test."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("WARPE_CL_CACHE_DIR", "XDG_CACHE_HOME", "OCL_ICD_VENDORS",
                        "WARPE_CL_TEST_SESSION_CACHE")}
    env["HOME"] = str(tmp_path)
    users = tmp_path / ".cache" / "warpe-cl"
    if how == "env":
        users = tmp_path / "mine"
        env["WARPE_CL_CACHE_DIR"] = str(users)
    users.mkdir(parents=True)
    env["WARPE_CL_TEST_CACHE_DIR"] = str(users) + "/"
    here = Path(__file__).resolve().parent
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                           str(here / "test_trust_cache.py"), "-k", "no_such_test"],
                          capture_output=True, text=True, env=env, cwd=here.parent,
                          timeout=120)
    out = done.stdout + done.stderr
    assert done.returncode == 4, out
    assert "is the user's own warpe-cl cache folder" in out
    assert not (users / "qualification.json").exists()
