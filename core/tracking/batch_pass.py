"""The trajectory check over a trial's frame ranges once a batch's range tasks are all done
(:func:`core.tracking.batch.trajectory_pass`, run by ``run_serial`` and ``run_batch``), and
what it leaves: the journal, the range reports and the batch summary's records in line.

Each range task of ``talus batch --ranges`` ran the trajectory check
(:mod:`core.tracking.flags_post`) over its own frames, fitting through the poses other ranges
had journaled when it started; its report (``<trial>.<bone>.<first>-<last>.json``) and its
record's ``flagged`` say what that pass found. Once every range of a (study, trial, bones) group
is complete, :func:`run_pass` judges all of the group's frames again in one pass (the journal's
other good poses as neighbours) and

* journals the frames whose flags changed (the review state the window shows);
* rewrites every range report of the group (atomically, as every report is written): each
  frame's entry in ``frames_done`` and ``flagged`` as the pass left it, ``summary.flagged``
  counted again, and a ``trajectory_pass`` section (the group, its ranges in frame order, the frames
  of this range the pass changed, its shared keyframes merged) — the rest of the report, and its
  layout, as the task wrote it;
* returns one entry per group — the batch summary's ``"trajectory_pass"`` — from which
  :func:`final_records` sets each range task's record's ``flagged`` to the count after the pass
  (``flagged_before_pass``: the task's own).

Before it judges, the pass makes the backward check's outcome (:mod:`core.tracking.backward_check`)
at a keyframe two ranges share independent of the order they ran (:func:`_shared_first_frames`):
each range checked it from its own side, the journal kept the outcome of the range recorded last and
each range's report its own. Where two or more of those ranges' reports can be read, the frame takes
every range's flags and notes of that check, the ranges in frame order (the backward one first; the
journal's own after them, an unreadable report's), and in its ``timing`` their backward
registrations' evaluations and seconds added up (``backward_ranges``: how many; a report written by an
earlier pass holds the sum, so a pass run again adds nothing) — flagged where either range flagged it,
and then, as in that range, neither judged by the trajectory check nor fitted through. The frame is
journaled again where its record changed, and named among the entry's changes where its flags changed
or it is flagged by the check (not for the other range's note alone); the entry's
``shared_keyframes`` lists the frames so merged, ``journaled_again`` every frame the pass journaled. A
group that is not judged — a range not complete (``skipped``) or the trajectory check off (``off``) —
has its shared keyframe merged all the same: the journal, the ranges' reports of that frame (a
``shared_keyframes`` section instead of ``trajectory_pass``) and their records' counts
(``tasks_flagged``); a merge that fails there is the entry's ``shared_error`` (the journal keeps the
range recorded last). A change's ``was_off_trajectory`` tells a frame whose trajectory flag came off
from one flagged otherwise (such a keyframe).

The merge gives such a keyframe its work once, named: its ``time_s`` and ``evaluations`` become those of
the sharing ranges' distinct registrations of it added up, and its ``timing`` says so
(:data:`SHARED_KEYS`: ``shared_ranges``, the ranges whose reports were read; ``shared_registrations``,
the registrations in the sum). A range run after the one that registered the keyframe takes it back
from the journal, as a resumed frame, and its report gave the other range's time and evaluations as
the frame's own (a serial batch: the range run first's, unnamed in both reports); that registration is
in the sum once, while ranges run side by side each registered the frame and both are. The journal and
the sharing ranges' reports say the same (each report's ``summary.evaluations`` moved with it: a sum
over the ranges' reports counts the keyframe's work in each); a
report written by an earlier pass holds the sum (its ``shared_registrations``), so a pass run again adds
nothing.

The pass reads the group's journals, judges them and journals its changes holding the bones'
journal locks (:meth:`core.tracking.batch_journal.SharedJournals.holding`), so a hand fix — a pose
the window or another process records, under the same lock — lands before the read (the pass
waits up to :data:`~core.tracking.batch_journal.JOURNAL_START_WAIT_S` for an append in flight,
then reads it: a hand-set pose is not judged) or is refused until the write is done; it is never
overtaken by the frame's tracked pose journaled again with a new flag. A writer that holds a bone
for good (``talus track``, the window) makes the pass an ``error`` entry.
A pass that fails while journaling its changes (e.g. a full disk) names in its
``error`` entry the frames it journaled before (``journaled``), which carry its flags; the
reports and records keep the ranges' own. A report that cannot be read or written (removed by
hand, its lock held) is named in the entry (``reports_unreadable``, ``reports_unwritten``) and
keeps the task's flags; the journal and the records hold the pass's. A group some of whose ranges
did not complete (failed, stopped, cancelled) is not judged: its entry says so under ``skipped``
and the ranges keep their own flags (but at a shared keyframe, above). :func:`pass_messages` words
an entry for ``talus batch`` and the window.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

__all__ = ["SHARED_KEYS", "final_records", "pass_messages", "run_pass"]

#: Changed frames named one by one in :func:`pass_messages` (the rest counted), as the window
#: names a single run's flagged frames.
MAX_NAMED = 10
#: The ``timing`` keys of a keyframe two ranges share, once merged (:func:`_shared_work`): how many
#: ranges' reports share it, and how many registrations its ``time_s`` and ``evaluations`` add up.
SHARED_KEYS = ("shared_ranges", "shared_registrations")


def run_pass(tasks: Sequence, records: Sequence[dict], settings) -> list[dict]:
    """:func:`core.tracking.batch.trajectory_pass` (see there and the module notes): ``tasks``
    are :class:`~core.tracking.batch.BatchTask`, ``settings`` a
    :class:`~core.tracking.batch.TaskSettings`."""
    done = {r.get("key") for r in records if r.get("status") == "complete"}
    groups: dict[tuple, list] = {}
    # each group's ranges in frame order, whatever order the tasks came in (the reports name them so)
    for t in sorted((t for t in tasks if t.frames is not None), key=_frame_order):
        groups.setdefault((t.study, t.trial, t.bones), []).append(t)
    out = []
    for (study, trial, bones), ts in groups.items():
        key = f"{Path(study).name}/{trial}/{'+'.join(bones)}"
        head = {"key": key, "ranges": [t.key for t in ts]}
        missing = [t.key for t in ts if t.key not in done]
        limit = settings.tracking_options(joint=len(bones) > 1).trajectory_limit
        # not judged: a range not complete, or the trajectory check off; the keyframe two ranges share
        # is given both ranges' backward checks all the same (_shared_first_frames)
        why = (dict(skipped=f"{len(missing)} of {len(ts)} ranges not complete "
                            f"({', '.join(missing[:3])}{' ...' if len(missing) > 3 else ''})") if missing
               else dict(off=True) if limit is None else {})
        if why and not _shared(ts):
            out.append(dict(head, **why) if missing else
                       dict(head, judged=0, flagged=0, changed=[], seconds=0.0, **why))
            continue
        frames = sorted({f for t in ts for f in t.order})
        failed = "shared_error" if why else "error"  # the merge alone failed: the ranges keep theirs
        try:
            out.append(dict(head, **_trial_pass(study, trial, bones, frames, ts, settings,
                                                None if why else limit), **why))
        except _PartlyJournaled as exc:  # some changed frames journaled: named
            cause = exc.__cause__
            out.append(dict(head, **{failed: f"{type(cause).__name__}: {cause}"}, journaled=exc.done,
                            changed_total=exc.total, **why))
        except Exception as exc:  # reported; the ranges' own flags stay in the journal
            out.append(dict(head, **{failed: f"{type(exc).__name__}: {exc}"}, **why))
    return out


def _frame_order(t) -> tuple:
    """A range task's place in frame order: its lowest frame, its highest, its key."""
    return (min(t.order), max(t.order), t.key)


def _shared(tasks: Sequence) -> bool:
    """Whether two or more of ``tasks`` start from the same frame (a keyframe both track)."""
    firsts = [int(t.order[0]) for t in tasks if t.order]
    return len(set(firsts)) < len(firsts)


class _PartlyJournaled(Exception):
    """The pass failed while journaling its changes, after ``done`` ([bone, frame]) of ``total``."""

    def __init__(self, done: list, total: int) -> None:
        super().__init__(f"{len(done)} of {total} changed frames journaled")
        self.done, self.total = done, total


def _trial_pass(study: str, trial_name: str, bones: Sequence[str], frames: Sequence[int],
                tasks: Sequence, settings, limit: float | None) -> dict:
    """:func:`run_pass` of one group: its journal read, judged, the changes recorded and its
    range reports rewritten. ``limit`` None: not judged (a range not complete, the trajectory check
    off), only the keyframe two ranges share given both ranges' backward checks."""
    from ..study import Study
    from .backward_check import FLAG as BACKWARD_FLAG
    from .backward_check import NOTE as BACKWARD_NOTE
    from .batch_journal import SharedJournals
    from .bones import bone_model
    from .flags_post import FLAG, UNCHECKED, apply_trajectory_flags, journal_neighbours
    from .results import FrameResult, TrackingResult

    t0 = time.perf_counter()
    with Study.open(study, mode="w", check_files=False) as st:
        shared = SharedJournals(st)
        # the centre track_study's bone model gives (the mask's centroid at the threshold), before
        # the journals are locked (the model takes a moment)
        centers = {} if limit is None else {
            b: bone_model(st.bone_volume(b), name=b, threshold=settings.threshold_hu, mesh=False).centroid
            for b in bones}
        # read, judge and journal the changes under the bones' journal locks: a hand fix (the window,
        # another process) lands before the read or after the write, never between (then it would
        # be overtaken by the frame's old pose with its new flag). Refused while another writer
        # (talus track, the window) holds a bone for good.
        with shared.holding(trial_name, bones):
            trial = shared.trial(trial_name)
            states = {b: trial.results(b) for b in bones}
            results = {(b, f): FrameResult.from_journal(b, r) for b in bones for f in frames
                       if (r := states[b].records.get(f)) is not None and r.kind == "tracked"}
            # a keyframe two ranges share: the backward check's outcomes of both ranges (their reports)
            merged, joined = _shared_first_frames(results, tasks, bones, st.read_report)
            if limit is None:  # not judged: the shared keyframes alone
                merged = {k: merged[k] for k in joined}
                out, changed = TrackingResult(tuple(bones), tuple(frames), merged, "complete", 0.0), []
            else:
                res = TrackingResult(tuple(bones), tuple(frames), merged, "complete", 0.0)
                # every other good pose of the journal a neighbour: outside the ranges, hand fixes in them
                near = journal_neighbours(states)
                out, changed = apply_trajectory_flags(res, centers, limit=limit, neighbours=near)
            # a shared keyframe given the ranges' outcomes: journaled again where its record changed,
            # named with the trajectory check's changes where its flags changed or it is flagged by the
            # check (whichever range the journal kept; not for the other range's note or timing alone)
            seen, at = {(fr.bone, fr.frame) for fr in changed}, {k: i for i, k in enumerate(results)}
            extra = [out.results[k] for k in joined if k not in seen and _differs(out.results[k], results[k])]
            listed = sorted(changed + [fr for fr in extra if fr.flags != results[(fr.bone, fr.frame)].flags
                                       or (fr.notes != results[(fr.bone, fr.frame)].notes
                                           and any(x.startswith(BACKWARD_FLAG) for x in fr.flags))],
                            key=lambda fr: at.get((fr.bone, fr.frame), len(at)))
            changed = sorted(changed + extra, key=lambda fr: at.get((fr.bone, fr.frame), len(at)))
            done = []
            try:
                for fr in changed:
                    trial.record_pose(fr.bone, fr.frame, fr.pose, score=fr.score,
                                      tracking=fr.journal_fields())
                    done.append([fr.bone, int(fr.frame)])
            except Exception as exc:  # (e.g. the disk full): those journaled are named
                if not done:
                    raise
                raise _PartlyJournaled(done, len(changed)) from exc
        final = out.results
        moved = {(fr.bone, int(fr.frame)) for fr in listed}
        names = [t.report_name for t in tasks]
        per_task, rewritten, unreadable, unwritten = {}, [], [], []
        unjudged: set[tuple[str, int]] = set()  # flagged in a report, not judged: e.g. no pose
        for t in tasks:
            mine = [(b, f) for f in t.order for b in bones if (b, f) in final]
            if limit is None and not mine:  # not judged, no shared keyframe of its own: as the task left it
                continue
            if limit is not None:  # judged: its frames' count, should its report not be read
                per_task[t.key] = sum(bool(final[k].flags) for k in mine)
            try:
                old = st.read_report("tracking", t.report_name)
            except Exception as exc:  # e.g. removed by hand: the journal and the summary still say it
                unreadable.append(f"{t.report_name}: {exc}")
                continue
            section = {"group": f"{Path(study).name}/{trial_name}/{'+'.join(bones)}", "ranges": names,
                       "judged": 0 if limit is None else len(results), "limit": limit,
                       "changed": [[b, int(f)] for b, f in mine if (b, f) in moved],
                       "shared_keyframes": [[b, int(f)] for b, f in mine if (b, f) in joined]}
            new = _final_report(old, [final[k] for k in mine], section,
                                "trajectory_pass" if limit is not None else "shared_keyframes")
            # the task's count as its report's: frames flagged without a pose (a view's frame
            # missing, outside a view) are in no journal, so the pass neither judged nor counted them
            per_task[t.key] = len(new["flagged"])
            unjudged.update((d.get("bone"), d.get("frame")) for d in new["flagged"]
                            if (d.get("bone"), d.get("frame")) not in final)
            if new != old:
                try:
                    st.write_report("tracking", t.report_name, new)
                except Exception as exc:  # the journal has the flags already: said, not an error
                    unwritten.append(f"{t.report_name}: {type(exc).__name__}: {exc}")
                    continue
                rewritten.append(t.report_name)
    flagged = sum(any(s.startswith(FLAG) for s in fr.flags) for fr in final.values())
    off = {k for k, fr in results.items() if any(s.startswith(FLAG) for s in fr.flags)}  # before the pass
    review = {b: sum(bool(fr.flags) for (bb, _), fr in final.items() if bb == b)
              + sum(bb == b for bb, _ in unjudged) for b in bones}
    entry = {"judged": 0 if limit is None else len(results), "flagged": 0 if limit is None else int(flagged),
             "changed": [[fr.bone, int(fr.frame)] for fr in listed],
             "changes": [{"bone": fr.bone, "frame": int(fr.frame), "flags": list(fr.flags),
                          "notes": [n for n in fr.notes if n.startswith((UNCHECKED, BACKWARD_NOTE))],
                          "was_flagged": bool(results[(fr.bone, fr.frame)].flags),
                          "was_off_trajectory": (fr.bone, fr.frame) in off}
                         for fr in listed],
             "shared_keyframes": [[b, int(f)] for b, f in joined],
             "journaled_again": [[fr.bone, int(fr.frame)] for fr in changed],
             "tasks_flagged": per_task, "reports": rewritten, "reports_unreadable": unreadable,
             "reports_unwritten": unwritten, "seconds": time.perf_counter() - t0}
    if limit is not None:  # the group's counts (not judged: only its shared keyframes were read)
        entry["review_flagged"] = review
    return entry


def _differs(a, b) -> bool:
    """Whether two results of a frame differ in what the shared keyframes' merge sets."""
    return (a.flags, a.notes, a.timing, a.time_s, a.evaluations) != (b.flags, b.notes, b.timing, b.time_s,
                                                                      b.evaluations)


def _shared_first_frames(results: dict, tasks: Sequence, bones: Sequence[str], read) -> tuple[dict, list]:
    """``results`` ((bone, frame) -> the journal's FrameResult) with the backward check's outcome
    (:mod:`core.tracking.backward_check`) at each first frame that two or more ranges share made
    independent of the order the ranges ran, and the (bone, frame) so given: the journal keeps the
    outcome of the range recorded last, each range's report its own (``read``: the study's
    ``read_report``, called with ``"tracking"`` and a report's name). Where two or more of those
    ranges' reports can be read the frame carries every range's flags and notes of that check, the
    ranges in frame order (the backward range first, whatever order ``tasks`` and the runs came in),
    the journal's own after them (those of an unreadable report), and in its ``timing`` the ranges'
    backward registrations added up (:func:`_backward_timing`); with fewer, the journal's outcome
    stays."""
    from dataclasses import replace

    from .backward_check import FLAG as BACKWARD
    from .backward_check import NOTE

    firsts: dict[int, list] = {}
    for t in sorted((t for t in tasks if t.order), key=_frame_order):
        firsts.setdefault(int(t.order[0]), []).append(t)
    out, joined = dict(results), []
    for f, ts in firsts.items():
        if len(ts) < 2 or not any((b, f) in results for b in bones):
            continue
        reports = []  # each readable range report's entries of frame f
        for t in ts:
            try:
                rep = read("tracking", t.report_name)
            except Exception:  # removed by hand, its lock held: the journal's outcome stays
                continue
            if isinstance(rep, dict):
                reports.append([d for key in ("frames_done", "flagged") if isinstance(rep.get(key), list)
                                for d in rep[key] if isinstance(d, dict) and d.get("frame") == f])
        if len(reports) < 2:
            continue
        for b in bones:
            fr = results.get((b, f))
            if fr is None:
                continue
            joined.append((b, f))
            mine = [next((d for d in r if d.get("bone") == b), None) for r in reports]
            mine = [d for d in mine if d is not None]
            flags = [str(s) for d in mine for s in d.get("flags") or () if str(s).startswith(BACKWARD)]
            notes = [str(s) for d in mine for s in d.get("notes") or () if str(s).startswith(NOTE)]
            flags += [s for s in fr.flags if s.startswith(BACKWARD)]
            notes += [s for s in fr.notes if s.startswith(NOTE)]
            # each entry's check (its one flag or note) with the timing it came with: a range that took
            # the frame back from the journal reports the other range's check, counted once
            runs = [([str(s) for s in (*(d.get("flags") or ()), *(d.get("notes") or ()))
                      if str(s).startswith((BACKWARD, NOTE))], d.get("timing")) for d in mine]
            runs.append(([s for s in (*fr.flags, *fr.notes) if s.startswith((BACKWARD, NOTE))], fr.timing))
            time_s, evaluations, shared = _shared_work(fr, mine, len(reports))
            new = replace(
                fr, flags=(*(s for s in fr.flags if not s.startswith(BACKWARD)), *dict.fromkeys(flags)),
                notes=(*(s for s in fr.notes if not s.startswith(NOTE)), *dict.fromkeys(notes)),
                timing={**(_backward_timing(fr.timing, runs) or {}), **shared},
                time_s=time_s, evaluations=evaluations)
            if _differs(new, fr):
                out[(b, f)] = new
    return out, joined


def _shared_work(fr, entries: Sequence[dict], ranges: int) -> tuple[float, int, dict]:
    """The frame's work as the ranges sharing it did it: ``(time_s, evaluations, keys)``, the time and
    evaluations of its distinct registrations added up and ``keys`` naming them in its ``timing``
    (:data:`SHARED_KEYS`: ``shared_ranges``, the ``ranges`` whose reports were read;
    ``shared_registrations``, how many registrations the sum holds). ``fr``: the journal's result;
    ``entries``: the readable range reports' entries of the frame. A range that took the frame back
    from the journal (run after the one that registered it) reports that registration's time and
    evaluations, which are counted once; ranges run side by side each registered it, and both are
    counted. An entry written by an earlier merge holds the sum already (its
    ``shared_registrations``): taken as it is, so that a pass run again adds nothing."""
    runs = [(float(d["time_s"] or 0.0), int(d.get("evaluations") or 0), d.get("timing")) for d in entries
            if "time_s" in d]  # (an entry without it reports no registration)
    runs.append((float(fr.time_s), int(fr.evaluations), fr.timing))
    summed = next(((t, e, tm) for t, e, tm in runs if isinstance(tm, dict) and SHARED_KEYS[1] in tm), None)
    if summed is not None:
        return summed[0], summed[1], {SHARED_KEYS[0]: int(summed[2].get(SHARED_KEYS[0], ranges)),
                                      SHARED_KEYS[1]: int(summed[2][SHARED_KEYS[1]])}
    distinct = list(dict.fromkeys((t, e) for t, e, _ in runs))
    return (sum(t for t, _ in distinct), sum(e for _, e in distinct),
            {SHARED_KEYS[0]: int(ranges), SHARED_KEYS[1]: len(distinct)})


def _backward_timing(timing: dict | None, runs: Sequence) -> dict | None:
    """``timing`` (the journal's) with the backward registrations of ``runs`` — (the check's flags and
    notes, ``timing``) of each range's report entry of the frame in frame order, the journal's last —
    added up: ``backward_evaluations`` and ``backward_s`` summed over the distinct checks (one
    message each; the same message twice is one registration, reported by the range that ran it and
    by one that took the frame back from the journal), ``backward_ranges`` how many. An entry written
    by an earlier merge holds the sum already (its ``backward_ranges``): taken as it is, so that a
    pass run again adds nothing. No check ran: ``timing`` as it is."""
    ran = [(m, t) for m, t in runs if isinstance(t, dict) and "backward_evaluations" in t]
    summed = next((t for _, t in ran if "backward_ranges" in t), None)
    if summed is not None:
        add = {k: summed[k] for k in ("backward_evaluations", "backward_s", "backward_ranges") if k in summed}
    else:
        one: dict = {}  # each check's first entry, in frame order
        for m, t in ran:
            if len(m) == 1:
                one.setdefault(m[0], t)
        if not one:
            return timing
        add = {"backward_evaluations": sum(int(t["backward_evaluations"]) for t in one.values()),
               "backward_s": sum(float(t.get("backward_s", 0.0)) for t in one.values()),
               "backward_ranges": len(one)}
    return {**{k: v for k, v in (timing or {}).items() if not k.startswith("backward_")}, **add}


def _final_report(report: dict, final: Sequence, section: dict, name: str = "trajectory_pass") -> dict:
    """``report`` (a range task's tracking report) with the frames of ``final`` (its frames as the
    pass left them, in tracking order) in ``frames_done`` and ``flagged``, ``summary.flagged``
    counted again, ``summary.evaluations`` moved by what the frames' evaluations moved (a shared
    keyframe's registrations added up) and ``section`` as ``name``."""
    by_key = {(fr.bone, int(fr.frame)): fr.to_dict() for fr in final}
    new, moved = dict(report), 0
    if isinstance(report.get("frames_done"), list):
        new["frames_done"] = [by_key.get((d.get("bone"), d.get("frame")), d) if isinstance(d, dict) else d
                              for d in report["frames_done"]]
        moved = sum(int(b.get("evaluations") or 0) - int(a.get("evaluations") or 0)
                    for a, b in zip(report["frames_done"], new["frames_done"], strict=True)
                    if isinstance(a, dict) and a is not b)
    # the task's flagged frames the pass did not judge (no pose: a view's frame missing, outside a
    # view; no longer a tracking result in the journal) stay listed
    kept = [d for d in report.get("flagged") or []
            if isinstance(d, dict) and (d.get("bone"), d.get("frame")) not in by_key]
    new["flagged"] = kept + [d for d in by_key.values() if d["flags"]]
    if isinstance(report.get("summary"), dict):
        new["summary"] = dict(report["summary"], flagged=len(new["flagged"]))
        if moved and isinstance(report["summary"].get("evaluations"), int):
            new["summary"]["evaluations"] = report["summary"]["evaluations"] + moved
    new[name] = section
    return new


def final_records(records: Sequence[dict], passes: Sequence[dict]) -> list[dict]:
    """``records`` (the tasks') with each judged range task's ``flagged`` the count after the
    pass (``passes``: :func:`run_pass`'s entries) and ``flagged_before_pass`` its own; the
    other records as they are."""
    after = {k: n for p in passes for k, n in (p.get("tasks_flagged") or {}).items()}
    return [dict(r, flagged=int(after[r["key"]]), flagged_before_pass=int(r.get("flagged", 0)))
            if r.get("key") in after else r for r in records]


def pass_messages(entry: dict, limit: int = MAX_NAMED) -> list[str]:
    """Lines telling one :func:`run_pass` entry: what was judged and the counts after the pass,
    then the frames the pass changed — the first ``limit`` named with their flags (or that the
    flag came off), one line counting the rest; a group not judged says why its ranges keep
    their own flags, and what the merge of the keyframe its ranges share changed."""
    key = entry.get("key", "?")
    n = len(entry.get("ranges") or ())
    its, each, ranges = ((f"its {n} ranges", "each range keeps", "the ranges'") if n != 1 else
                         ("its 1 range", "the range keeps", "the range's"))  # not 'its 1 ranges'
    if entry.get("error") and entry.get("journaled"):
        done = entry["journaled"]
        return [f"{key}: the trajectory check over {its} failed ({entry['error']}) after journaling "
                f"{len(done)} of {entry.get('changed_total', '?')} changed frames ({_named(done, limit)}): "
                f"those carry its flags, {ranges} reports and records their own"]
    if entry.get("error"):
        return [f"{key}: the trajectory check over {its} failed ({entry['error']}); {each} its own flags"]
    if entry.get("skipped") or entry.get("off"):
        shared = " (the keyframe they share given both ranges' backward checks)" if entry.get(
            "shared_keyframes") else ""
        lines = [f"{key}: the trajectory check over {its} did not run ({entry['skipped']}); {each} its own "
                 f"flags{shared}" if entry.get("skipped") else f"{key}: trajectory check off{shared}"]
        if entry.get("shared_error"):
            done = entry.get("journaled") or []
            after = (f" after journaling {len(done)} of {entry.get('changed_total', '?')} ("
                     f"{_named(done, limit)})") if done else ""
            lines.append(f"{key}: the backward checks of the keyframe its ranges share not merged "
                         f"({entry['shared_error']}){after}; the journal keeps the range recorded last")
        return lines + _change_lines(key, entry.get("changes") or [], limit)
    review = entry.get("review_flagged") or {}
    total = sum(review.values())
    per_bone = f" ({', '.join(f'{b} {c}' for b, c in review.items())})" if len(review) > 1 else ""
    changes = entry.get("changes") or []
    lines = [f"{key}: {total} flagged for review{per_bone} after the trajectory check over {its}"
             f"{' together' if n != 1 else ''} ({entry.get('judged', 0)} bone-frames judged, "
             f"{entry.get('flagged', 0)} off the trajectory, {len(changes)} changed by the check)"]
    lines += _change_lines(key, changes, limit)
    missed = list(entry.get("reports_unwritten") or ()) + list(entry.get("reports_unreadable") or ())
    if missed:
        lines.append(f"{key}: {len(missed)} range report{'s' if len(missed) > 1 else ''} not rewritten with "
                     f"the flags after the check ({'; '.join(missed)})")
    return lines


def _named(done: Sequence, limit: int) -> str:
    """``[bone, frame]`` pairs named, the first ``limit``."""
    return ", ".join(f"{b} frame {int(f)}" for b, f in done[:limit]) + (" ..." if len(done) > limit else "")


def _change_lines(key: str, changes: Sequence[dict], limit: int) -> list[str]:
    """A line per changed frame of :func:`pass_messages` (the first ``limit``), one counting the rest."""
    from .flags_post import FLAG

    lines = []
    for c in changes[:limit]:
        flags = list(c.get("flags") or ())
        # a frame flagged otherwise, e.g. a shared keyframe's backward check (its flag from another
        # range), was not off the trajectory before (an entry without the key: as before it)
        was_off = c.get("was_off_trajectory", c.get("was_flagged", True))
        what = ("; ".join(flags) if any(s.startswith(FLAG) for s in flags) or (flags and not was_off) else
                f"no longer off the trajectory (still flagged: {'; '.join(flags)})" if flags else
                f"{'no longer' if c.get('was_flagged') else 'not'} flagged, {'; '.join(c['notes'])}"
                if c.get("notes") else "no longer flagged")
        lines.append(f"{key}: {c['bone']} frame {int(c['frame'])}: {what}")
    if len(changes) > limit:
        lines.append(f"{key}: ... and {len(changes) - limit} more frames changed by the check: "
                     "the review panel lists the flagged ones")
    return lines
