"""The exchange protocol of BalancedMaterial: a call's rows go from the home ranks of the
points to their workers, the inner material runs there, results come back.

    send    home -> worker: point index and the call's rows              (Alltoallv)
    work    the worker runs the inner material on its slots; nothing raises here
    reply   worker -> home: result rows, status, cost                    (Alltoallv)
            and per home rank the first failure, first flag, fatal error (alltoall)

Statuses travel as floats: 0 ok, > 0 flagged, < 0 failed (`STATUS_FAILED` for a
ConstitutiveError), `STATUS_FATAL` for any other exception of the inner material (a bug,
raised on the home rank once every exchange of the call is done).
"""
import time
from typing import NamedTuple

import numpy as np
from mpi4py import MPI

from ..constitutive import ConstitutiveError

STATUS_FAILED = -1
#: status of a point whose inner material raised something other than ConstitutiveError
STATUS_FATAL = -np.inf


class Sent(NamedTuple):
    """What `send` did: the rows of `points[order]` went to their workers."""
    order: np.ndarray         # the points in the order sent (grouped by worker rank)
    send_counts: np.ndarray   # rows sent to each rank
    received: np.ndarray      # rows received; column 0: the point's index on its home rank
    source: np.ndarray        # home rank of each received row
    recv_counts: np.ndarray   # rows received from each rank


class Work(NamedTuple):
    """What the inner material did on the received rows (one entry per row)."""
    status: np.ndarray        # float: 0 ok, > 0 flagged, < 0 failed, STATUS_FATAL
    cost: np.ndarray          # the inner material's reported cost
    wall: np.ndarray          # wall seconds [s]
    messages: dict            # row -> words (a failure, flag or fatal error)


class Reply(NamedTuple):
    """The results on the home rank, rows in the order sent."""
    rows: np.ndarray
    status: np.ndarray        # int32; a fatal point reads STATUS_FAILED
    cost: np.ndarray
    failure: str              # the first failure of this rank's points ("" none)
    flag: str                 # the first flag
    fatal: str                # the first fatal error


def offsets(counts):
    return np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)


def alltoallv(comm, rows, send_counts, recv_counts, width):
    """Rows (float64, `width` columns) grouped by destination rank -> rows grouped by source."""
    send = np.ascontiguousarray(rows, dtype=np.float64).reshape(-1)
    recv = np.empty(int(np.sum(recv_counts)) * width, dtype=np.float64)
    sc, rc = np.asarray(send_counts) * width, np.asarray(recv_counts) * width
    comm.Alltoallv([send, (sc.tolist(), offsets(sc).tolist()), MPI.DOUBLE],
                   [recv, (rc.tolist(), offsets(rc).tolist()), MPI.DOUBLE])
    return recv.reshape(-1, width)


def concatenate(parts):
    """Per-key concatenation of exported struct-of-arrays dicts (in order)."""
    parts = [p for p in parts if p]
    if len(parts) == 1:
        return parts[0]
    return {key: np.concatenate([np.asarray(p[key]) for p in parts]) for key in parts[0]} if parts else {}


def runs(values):
    """(start, stop) of the maximal runs of equal values."""
    if not len(values):
        return []
    cuts = np.flatnonzero(np.diff(values)) + 1
    starts = np.concatenate([[0], cuts])
    stops = np.concatenate([cuts, [len(values)]])
    return list(zip(starts.tolist(), stops.tolist()))


def send(comm, worker, points, rows):
    """Rows of home `points` (worker: the worker rank of every home point) to their workers."""
    dest = worker[points]
    order = np.argsort(dest, kind="stable")
    send_counts = np.bincount(dest, minlength=comm.size).astype(np.int64)
    recv_counts = np.array(comm.alltoall(send_counts.tolist()), dtype=np.int64)
    rows = np.column_stack([points[order].astype(np.float64), rows[order]])
    received = alltoallv(comm, rows, send_counts, recv_counts, rows.shape[1])
    source = np.repeat(np.arange(comm.size), recv_counts)
    return Sent(order, send_counts, received, source, recv_counts)


def reply(comm, rows, work, sent):
    """Results back to the home ranks; the messages of each home rank's points (first
    failure, else first flag; a fatal error) with alltoall."""
    status = work.status
    back = alltoallv(comm, np.column_stack([rows, status, work.cost]), sent.recv_counts, sent.send_counts,
                     rows.shape[1] + 2)
    per_source = [["", "", ""] for _ in range(comm.size)]
    for k, text in work.messages.items():
        entry = per_source[sent.source[k]]
        slot = 2 if status[k] == STATUS_FATAL else (0 if status[k] < 0 else 1)
        if not entry[slot]:
            entry[slot] = text
    got = comm.alltoall(per_source)
    failure = next((g[0] for g in got if g[0]), "")
    flag = next((g[1] for g in got if g[1]), "")
    fatal = next((g[2] for g in got if g[2]), "")
    status_back = back[:, -2]
    status_back[np.isinf(status_back)] = STATUS_FAILED
    return Reply(back[:, :-2], status_back.astype(np.int32), back[:, -1], failure, flag, fatal)


def work(per_point, all_points, slots, source):
    """Run the inner material on the received `slots`: `per_point(k)` for each (timed one by
    one: the cost of each point), or, for a material that updates every row at once,
    `all_points()` once (time and cost shared). Nothing raises here."""
    n = len(slots)
    status, cost, wall, messages = np.zeros(n), np.zeros(n), np.zeros(n), {}

    def call(function):
        try:
            report = function()
        except ConstitutiveError as error:
            return None, STATUS_FAILED, str(error)
        except Exception as error:   # a bug must not leave the other ranks in the exchange
            return None, STATUS_FATAL, f"{type(error).__name__}: {error}"
        return report, None, ""

    if per_point is not None:
        for k in range(n):
            start = time.perf_counter()
            report, code, text = call(lambda: per_point(k))
            wall[k] = time.perf_counter() - start
            if report is not None:
                status[k], cost[k] = report.status[0], report.cost[0]
                text = report.message if report.status[0] != 0 else ""
            elif code is not None:
                status[k] = code
            if text:
                messages[k] = text
            if status[k] == STATUS_FATAL:
                # the same bug would follow: skip the rest, each home rank concerned told why
                status[k:] = STATUS_FATAL
                for s in np.unique(source[k:]):
                    messages.setdefault(k + int(np.flatnonzero(source[k:] == s)[0]), text)
                break
    elif n:
        start = time.perf_counter()
        report, code, text = call(all_points)
        wall[:] = (time.perf_counter() - start) / n
        if report is not None:
            status[:], cost[:] = np.asarray(report.status)[slots], np.asarray(report.cost)[slots]
            text = report.message
        elif code is not None:
            status[:] = code
        if text:   # the one message goes to the first point of each home rank it concerns
            for s in np.unique(source):
                ks = np.flatnonzero((source == s) & (status != 0))
                if ks.size:
                    messages[int(ks[0])] = text
    return Work(status, cost, wall, messages)


def fatal(source, error):
    """The Work of a call that could not run: every point fatal, each home rank told why."""
    n = len(source)
    return Work(np.full(n, STATUS_FATAL), np.zeros(n), np.zeros(n),
                {int(np.flatnonzero(source == s)[0]): error for s in np.unique(source)})
