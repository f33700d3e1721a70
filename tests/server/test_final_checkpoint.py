"""A member that stops cleanly marks its last checkpoints ``final`` (a Zenoh attachment), and
the standby's intake hands the mark to its custody machine: a failover from a final
checkpoint publishes nothing again (tests/server/test_custody_machine.py G4b), so a stop
answers each frame exactly once, while a failover from a killed member's last checkpoint
publishes the last message heard again (the kill may have cut its put short)."""

from __future__ import annotations

from simpletrack.server.intake import FINAL_CHECKPOINT, Inbound, Intake, Kind, WorkQueue
from simpletrack.server.settings import Backpressure
from simpletrack.session import ZenohOptions, open_session
from simpletrack.spawn import free_port
from simpletrack.wire.codec import pack
from tests.service_helpers import wait_for


def test_the_final_mark_of_a_checkpoint_reaches_the_standby_s_worker() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    q = WorkQueue(maxsize=4)
    intake = Intake([q], Backpressure.DROP_OLDEST, lambda key: None, lambda i, r: None)
    with (
        open_session(ZenohOptions(listen=[endpoint])) as standby,
        open_session(ZenohOptions(connect=[endpoint])) as owner,
    ):
        sub = standby.declare_subscriber("cp/**", lambda s: intake.checkpoint(s, "v/s"))
        try:
            sent = {"cp/v/stopped": FINAL_CHECKPOINT, "cp/v/live": None}

            def put_both() -> bool:
                # Again until both wait (one per key): the sessions' link may still open.
                for key, attachment in sent.items():
                    owner.put(key, pack({"written_ns": 1}), attachment=attachment)
                return q.checkpoints == len(sent)

            wait_for(put_both, timeout=5.0, what="both members' checkpoints")
            items = [q.get(timeout=1.0) for _ in sent]
            assert all(isinstance(i, Inbound) and i.kind is Kind.CHECKPOINT for i in items)
            finals = {i.key: i.final for i in items if isinstance(i, Inbound)}
            assert finals == {"cp/v/stopped": True, "cp/v/live": False}
        finally:
            sub.undeclare()
