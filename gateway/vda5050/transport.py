"""VDA 5050 vehicles as robots of the gateway: a second robot transport beside websockets.

Each configured vehicle is a :class:`protocol.vda5050.robot.VdaRobot` on an in-memory link
served by :meth:`Gateway.serve_link` (the same sessions, engine, executor and journal as a
websocket robot); its :class:`protocol.vda5050.master.VehicleMaster` talks to the vehicle
through one shared MQTT connection (:class:`gateway.vda5050.driver.MasterClient`). The link is
up while the vehicle's ``connection`` topic says ONLINE: OFFLINE or the last will
(CONNECTIONBROKEN) closes it, and the next ONLINE opens a new one with a ``hello``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
import time
from types import TracebackType
from typing import TYPE_CHECKING

import aiomqtt

from gateway.server.items import OwnerCall
from gateway.server.wire.auth import Peer
from gateway.server.wire.transport import MemoryClient, memory_pair
from gateway.vda5050.config import Vda5050Config
from gateway.vda5050.driver import MasterClient
from gateway.vda5050.errands import ShiftErrands, give_up_failed
from protocol.codec import ProtocolError, decode, encode
from protocol.messages import (
    HEADINGS,
    Action,
    Pose,
    Welcome,
    action_id,
    action_run,
    parse_action_id,
)
from protocol.vda5050.master import (
    Effect,
    ErrandFailed,
    LinkState,
    VehicleMaster,
    consecutive_ids,
)
from protocol.vda5050.robot import VdaRobot

if TYPE_CHECKING:
    from gateway.server.gateway import Gateway

log = logging.getLogger("fleetgate.vda5050")


class BrokerUnreachable(ValueError):
    """The MQTT broker refused the master control or cannot be reached."""


class _Vehicle:
    """One vehicle's gateway side: its robot and its current in-memory link."""

    def __init__(self, robot: VdaRobot) -> None:
        self.robot = robot
        self.client: MemoryClient | None = None
        self.tasks: list[asyncio.Task[None]] = []
        self.out: asyncio.Queue[str] = asyncio.Queue()
        self.state_period_s = 5.0
        self.flush_due = False


class VdaTransport:
    """``async with VdaTransport(gateway, config):`` drives the configured vehicles."""

    def __init__(self, gateway: Gateway, config: Vda5050Config) -> None:
        self.gateway = gateway
        self.config = config
        turning = gateway.config.motion == "turning"
        nodes = config.nodes()
        self.vehicles: dict[int, _Vehicle] = {}
        masters: list[VehicleMaster] = []
        lifelong = gateway.config.lifelong is not None
        errands = ShiftErrands(gateway.engine, {v.robot_id for v in config.vehicles})
        instance = secrets.token_hex(4) + "."  # this start's instant action ids are new
        for v in config.vehicles:
            master = VehicleMaster(config.topics(v), config.version_of(v), nodes,
                                   resend_s=config.resend_s, continuous=lifelong,
                                   errand=errands if lifelong else None, ids=self._ids,
                                   instance=instance)
            masters.append(master)
            self.vehicles[id(master)] = _Vehicle(VdaRobot(v.robot_id, master, turning=turning,
                                                          plan_of=self._plan_of))
        self.mqtt = MasterClient(config.broker, masters, self._effect, on_state=self._state)
        self._task: asyncio.Task[None] | None = None

    async def __aenter__(self) -> VdaTransport:
        """Connect to the broker; BrokerUnreachable (a ValueError) if that fails."""
        self._task = asyncio.create_task(self._keep_connected())
        connected = asyncio.ensure_future(self.mqtt.connected.wait())
        done, _ = await asyncio.wait({self._task, connected},
                                     return_when=asyncio.FIRST_COMPLETED)
        if self._task in done:
            connected.cancel()
            try:
                self._task.result()
            except aiomqtt.MqttError as exc:
                raise BrokerUnreachable(f"cannot reach the MQTT broker at "
                                        f"{self.config.broker.url}: {exc}") from None
        return self

    async def _keep_connected(self) -> None:
        """Run the master's connection; once it was up, reconnect every second after a
        loss (vehicles keep their orders meanwhile, section 6.2)."""
        while True:
            try:
                await self.mqtt.run()
            except aiomqtt.MqttError as exc:
                if not self.mqtt.connected.is_set():
                    raise
                log.warning("MQTT broker connection lost; reconnecting",
                            extra={"error": str(exc)[:300]})
                await asyncio.sleep(1.0)

    async def __aexit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                        tb: TracebackType | None) -> None:
        for vehicle in self.vehicles.values():
            await self._close(vehicle)
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await self._task

    def _steps(self, plan: int, robot: int) -> list[int] | None:
        """The plan steps of ``robot``'s actions (waits are none under ``drop_waits``) in the
        executor's current plan, if that is plan ``plan``; else None."""
        executor = self.gateway.engine.executor
        adg = getattr(executor, "adg", None)
        if adg is None or getattr(executor, "plan_id", None) != plan:
            return None
        return [adg.step_of[v] for v in range(adg.first[robot], adg.first[robot + 1])]

    def _plan_of(self, action: Action) -> list[Action]:
        """Every action of the robot in the executor's current plan, if ``action`` is one of
        them (the orders' horizon); empty for a lifelong shift or an older plan."""
        plan, robot, _ = parse_action_id(action.action_id)
        if self._steps(plan, robot) is None:
            return []
        executor = self.gateway.engine.executor
        adg = executor.adg  # type: ignore[union-attr]
        run = action_run(action.action_id)
        tx = executor.monitor.tx  # type: ignore[union-attr]
        out = []
        for v in range(adg.first[robot], adg.first[robot + 1]):
            step = adg.step_of[v]
            h0, h1 = adg.heading(robot, step), adg.heading(robot, step + 1)
            out.append(Action(msg_id=f"plan-{step}", seq=0, sequence=step,
                              action_id=action_id(plan, robot, step, run),
                              src=Pose(cell=adg.src[v], heading=None if h0 is None
                                       else HEADINGS[h0]),
                              dst=Pose(cell=adg.dst[v], heading=None if h1 is None
                                       else HEADINGS[h1]), duration_ms=tx[v]))
        return out

    def _ids(self, key: str, first: int, count: int) -> list[str | None]:
        """The ids of the ``count`` actions of an order named after action ``first`` of plan
        key ``key`` (``[run.]plan.robot``): in a lifelong shift actions are numbered over the
        run and each has its segment; in a plan the robot's actions are its plan steps (waits
        left out under ``drop_waits``). Fewer if the plan has no more; None for a shift's
        action whose segment the executor no longer keeps (it finished long ago)."""
        *head, plan_s, robot_s = key.split(".")
        run, plan, robot = (head[0] if head else ""), int(plan_s), int(robot_s)
        shift = self.gateway.engine.lifelong
        if shift is not None:
            executor = shift.executor
            segments = [executor.segment_of(robot, n) for n in range(first, first + count)]
            return [None if seg < 0 else action_id(seg, robot, n, run)
                    for n, seg in enumerate(segments, first)]
        steps = self._steps(plan, robot)
        if steps is None:
            return consecutive_ids(key, first, count)
        out: list[str | None] = [action_id(plan, robot, s, run) for s in steps if s >= first]
        return out[:count]

    # ------------------------------------------------------------------ vehicle side
    def _effect(self, master: VehicleMaster, effect: Effect) -> None:
        vehicle = self.vehicles[id(master)]
        if isinstance(effect, LinkState):
            log.info("vehicle link", extra={"robot": vehicle.robot.robot_id,
                                            "state": effect.state})
            if effect.online:
                self._open(vehicle)
            else:
                asyncio.get_running_loop().create_task(self._close(vehicle))
            return
        if isinstance(effect, ErrandFailed):
            self.gateway.engine.queue.put_nowait(OwnerCall(
                lambda: self._give_up(vehicle, effect)))
            return
        vehicle.robot.vehicle(effect)
        self._flush(vehicle)

    def _give_up(self, vehicle: _Vehicle, failed: ErrandFailed) -> None:
        """In the owner task: cancel the task of a failed pick (then the vehicle's action
        finishes), or leave the action blocked (a drop: the task has an errand done)."""
        why = give_up_failed(self.gateway.engine, failed.errand)
        if why is None:
            log.warning("a vehicle's errand failed: its task is cancelled", extra={
                "robot": vehicle.robot.robot_id, "errand": failed.errand})
            vehicle.robot.master.give_up(failed.errand, time.time())
            self._flush(vehicle)
        else:
            log.warning("a vehicle's errand failed: the action stays blocked for an operator",
                        extra={"robot": vehicle.robot.robot_id, "errand": failed.errand,
                               "error": why[:300]})

    def _state(self, master: VehicleMaster) -> None:
        vehicle = self.vehicles[id(master)]
        vehicle.robot.state_seen()
        self._flush(vehicle)

    def _flush(self, vehicle: _Vehicle) -> None:
        self.mqtt.flush(vehicle.robot.master)
        for message in vehicle.robot.drain():
            vehicle.out.put_nowait(encode(message))

    # ------------------------------------------------------------------ gateway side
    def _open(self, vehicle: _Vehicle) -> None:
        robot = vehicle.robot
        client, link = memory_pair(Peer("robot", robot.robot_id), self.gateway.config.send_queue)
        vehicle.client = client
        vehicle.out = asyncio.Queue()
        loop = asyncio.get_running_loop()
        vehicle.tasks = [loop.create_task(self.gateway.serve_link(link)),
                         loop.create_task(self._read(vehicle, client)),
                         loop.create_task(self._write(vehicle, client)),
                         loop.create_task(self._states(vehicle))]
        robot.connected(time.time())
        self._flush(vehicle)

    async def _close(self, vehicle: _Vehicle) -> None:
        vehicle.robot.disconnected()
        client, tasks = vehicle.client, vehicle.tasks
        vehicle.client, vehicle.tasks = None, []
        if client is not None:
            await client.close()
        for task in tasks[1:]:
            task.cancel()
        for task in tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task

    async def _read(self, vehicle: _Vehicle, client: MemoryClient) -> None:
        async for text in client:
            try:
                message = decode(text)
            except ProtocolError as exc:
                log.warning("undecodable gateway message", extra={"error": str(exc)[:300]})
                continue
            if isinstance(message, Welcome):
                vehicle.state_period_s = message.state_period_ms / 1000
            vehicle.robot.receive(message, time.time())
            if not vehicle.flush_due:  # after every message already queued has been read
                vehicle.flush_due = True
                asyncio.get_running_loop().call_soon(self._commit, vehicle)

    def _commit(self, vehicle: _Vehicle) -> None:
        vehicle.flush_due = False
        vehicle.robot.commit(time.time())
        self._flush(vehicle)

    async def _write(self, vehicle: _Vehicle, client: MemoryClient) -> None:
        while True:
            await client.send(await vehicle.out.get())

    async def _states(self, vehicle: _Vehicle) -> None:
        while True:
            await asyncio.sleep(vehicle.state_period_s)
            vehicle.robot.state()
            self._flush(vehicle)
