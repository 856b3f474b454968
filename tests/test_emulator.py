"""The servo-bus emulator driven by the unmodified dynamixel-sdk over a pty."""

from __future__ import annotations

import time
from typing import Callable, Iterator

import numpy as np
import pytest
from dynamixel_sdk import (
    GroupBulkRead,
    GroupBulkWrite,
    GroupSyncRead,
    GroupSyncWrite,
    PacketHandler,
    Protocol2PacketHandler,
)
from dynamixel_sdk.robotis_def import COMM_RX_CORRUPT, COMM_RX_TIMEOUT, COMM_SUCCESS

from drivers.dynamixel.control_table import _sdk_layout
from drivers.dynamixel.io import BlockingPortHandler, StuffingPacketHandler
from drivers.dynamixel.protocol import ALERT_BIT, BROADCAST_ID, Instruction, StatusError, build_instruction
from drivers.dynamixel.units import OperatingMode
from drivers.emulator import (
    XL430_W250,
    XM430_W350,
    XM540_W270,
    DynamixelBusEmulator,
    InertiaPlant,
    ServoModel,
    model_spec,
    supported_models,
)

pytestmark = pytest.mark.timeout(30)

BAUD = 1_000_000
FAST = {"Baud Rate": 3, "Return Delay Time": 0}  # 1 Mbps like the bench's bus

# Control-table addresses (X-series)
OPERATING_MODE, HOMING_OFFSET, MAX_POS, TORQUE, LED = 11, 20, 48, 64, 65
STATUS_RETURN_LEVEL, HW_ERROR, GOAL_POS, PROFILE_VEL = 68, 70, 116, 112
MOVING, PRESENT_CURRENT, PRESENT_VEL, PRESENT_POS = 122, 126, 128, 132


def u32(value: int) -> int:
    return value & 0xFFFFFFFF


def s32(value: int) -> int:
    return value - (1 << 32) if value & 0x80000000 else value


def wait_for(condition: Callable[[], bool], timeout: float = 3.0, period: float = 0.02) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(period)
    return condition()


def make_bus(
    ids=(1, 2), *, plant: InertiaPlant | None = None, servo_kwargs=None, registers=None, **bus_kwargs
) -> DynamixelBusEmulator:
    servos = {
        i: ServoModel(XM430_W350, registers={**FAST, **(registers or {})}, **(servo_kwargs or {}))
        for i in ids
    }
    if plant is None:
        plant = InertiaPlant(len(ids), inertia=0.01, viscous=0.02)
    return DynamixelBusEmulator(servos, plant, **bus_kwargs)


@pytest.fixture
def bus() -> Iterator[DynamixelBusEmulator]:
    with make_bus() as b:
        yield b
    assert not b.errors, b.errors


def open_port(bus: DynamixelBusEmulator, baud: int = BAUD) -> BlockingPortHandler:
    port = BlockingPortHandler(bus.port)
    assert port.openPort()
    assert port.setBaudRate(baud)
    return port


@pytest.fixture
def port(bus) -> Iterator[BlockingPortHandler]:
    p = open_port(bus)
    yield p
    p.closePort()


@pytest.fixture
def ph() -> StuffingPacketHandler:
    return StuffingPacketHandler()


@pytest.fixture
def stock() -> Protocol2PacketHandler:
    return PacketHandler(2.0)


@pytest.fixture(params=["stock", "stuffing"])
def any_ph(request) -> Protocol2PacketHandler:
    """Both handlers, for traffic that never needs stuffing."""
    return PacketHandler(2.0) if request.param == "stock" else StuffingPacketHandler()


def ok(result_error: tuple[int, int]) -> None:
    result, error = result_error
    assert (result, error) == (COMM_SUCCESS, 0), f"result={result} error={error:#04x}"


def raw_transaction(port, packet: bytes, timeout_ms: float = 50.0):
    """Send raw bytes; return (status packet list, result) as the SDK's rxPacket would."""
    port.clearPort()
    port.writePort(packet)
    port.setPacketTimeoutMillis(timeout_ms)
    port.is_using = True
    return StuffingPacketHandler().rxPacket(port, False)


# -- tables --------------------------------------------------------------------------


def test_control_tables_follow_the_sdk_model_files() -> None:
    assert supported_models() == {
        1020: "XM430-W350",
        1060: "XL430-W250",
        1070: "XC430-W150",
        1120: "XM540-W270",
        1190: "XL330-M077",
        1200: "XL330-M288",
    }
    for number in supported_models():
        spec = model_spec(number)
        layout = {name: (a, s) for a, s, name in _sdk_layout(spec.name.lower().replace("-", "_") + ".model")}
        for register in spec.table:
            assert layout[register.name] == (register.address, register.size)
    xm = model_spec(XM430_W350)
    assert xm.table["Model Number"].default == 1020
    assert xm.table["Goal Position"].address == 116 and xm.table["Goal Position"].signed
    assert xm.table["Current Limit"].default == 1193
    assert abs(xm.motor.kt - 1.78) < 0.01
    assert "Current Limit" not in model_spec(XL430_W250).table
    assert model_spec(XM540_W270).table["Current Limit"].default == 2047


# -- instructions through the unmodified SDK --------------------------------------------


def test_ping_with_stock_and_stuffing_handlers(bus, port, ph, stock) -> None:
    for handler in (stock, ph):
        assert handler.ping(port, 1) == (1020, COMM_SUCCESS, 0)
        assert handler.ping(port, 2) == (1020, COMM_SUCCESS, 0)


def test_broadcast_ping_finds_every_servo(bus, port, ph) -> None:
    found, result = ph.broadcastPing(port)
    assert result == COMM_SUCCESS
    assert found == {1: [1020, 48], 2: [1020, 48]}


def test_read_write(bus, port, stock) -> None:
    assert stock.read2ByteTxRx(port, 1, 0) == (1020, COMM_SUCCESS, 0)
    ok(stock.write1ByteTxRx(port, 1, LED, 1))
    assert stock.read1ByteTxRx(port, 1, LED) == (1, COMM_SUCCESS, 0)
    assert bus.servo(1).get("LED") == 1
    assert stock.read4ByteTxRx(port, 2, PRESENT_POS)[0] == 2048


def test_reg_write_then_action(bus, port, ph) -> None:
    ok(ph.regWriteTxRx(port, 1, PROFILE_VEL, 4, [100, 0, 0, 0]))
    assert ph.read4ByteTxRx(port, 1, PROFILE_VEL)[0] == 0
    assert ph.read1ByteTxRx(port, 1, 69)[0] == 1  # Registered Instruction
    assert ph.action(port, 1) == COMM_SUCCESS
    time.sleep(0.05)  # the SDK does not read ACTION's status; let it arrive and be flushed
    assert ph.read4ByteTxRx(port, 1, PROFILE_VEL)[0] == 100
    # ACTION with nothing registered: Instruction Error.
    rx, result = raw_transaction(port, build_instruction(1, Instruction.ACTION))
    assert result == COMM_SUCCESS and rx[8] == StatusError.INSTRUCTION


def test_sync_write_and_sync_read(bus, port, any_ph) -> None:
    ok(any_ph.write1ByteTxRx(port, 1, TORQUE, 1))
    ok(any_ph.write1ByteTxRx(port, 2, TORQUE, 1))
    writer = GroupSyncWrite(port, any_ph, GOAL_POS, 4)
    assert writer.addParam(1, list((2048 + 200).to_bytes(4, "little")))
    assert writer.addParam(2, list((2048 - 300).to_bytes(4, "little")))
    assert writer.txPacket() == COMM_SUCCESS
    reader = GroupSyncRead(port, any_ph, PRESENT_POS, 4)
    reader.addParam(1)
    reader.addParam(2)

    def settled() -> bool:
        if reader.txRxPacket() != COMM_SUCCESS:
            return False
        p1, p2 = s32(reader.getData(1, PRESENT_POS, 4)), s32(reader.getData(2, PRESENT_POS, 4))
        return abs(p1 - 2248) <= 3 and abs(p2 - 1748) <= 3

    assert wait_for(settled)


def test_fast_sync_read(bus, port, any_ph) -> None:
    bus.servo(1).force("Present Position", 1111)
    bus.servo(2).force("Present Position", -2222)
    reader = GroupSyncRead(port, any_ph, PRESENT_POS, 4)
    reader.addParam(1)
    reader.addParam(2)
    assert reader.fastSyncRead() == COMM_SUCCESS
    assert s32(reader.getData(1, PRESENT_POS, 4)) == 1111
    assert s32(reader.getData(2, PRESENT_POS, 4)) == -2222


def test_bulk_write_and_bulk_read(bus, port, any_ph) -> None:
    writer = GroupBulkWrite(port, any_ph)
    assert writer.addParam(1, LED, 1, [1])
    assert writer.addParam(2, PROFILE_VEL, 4, [77, 0, 0, 0])
    assert writer.txPacket() == COMM_SUCCESS
    reader = GroupBulkRead(port, any_ph)
    assert reader.addParam(1, LED, 1)
    assert reader.addParam(2, PROFILE_VEL, 4)
    assert wait_for(lambda: reader.txRxPacket() == COMM_SUCCESS and reader.getData(2, PROFILE_VEL, 4) == 77)
    assert reader.getData(1, LED, 1) == 1
    assert reader.fastBulkRead() == COMM_SUCCESS
    assert reader.getData(1, LED, 1) == 1 and reader.getData(2, PROFILE_VEL, 4) == 77


def test_reboot_and_factory_reset(bus, port, any_ph) -> None:
    ok(any_ph.write1ByteTxRx(port, 1, TORQUE, 1))
    ok(any_ph.write1ByteTxRx(port, 1, LED, 1))
    ok(any_ph.reboot(port, 1))
    assert any_ph.read1ByteTxRx(port, 1, TORQUE) == (0, COMM_SUCCESS, 0)
    assert any_ph.read1ByteTxRx(port, 1, LED)[0] == 0
    ok(any_ph.write4ByteTxRx(port, 2, HOMING_OFFSET, 5))
    ok(any_ph.factoryReset(port, 2, 0x02))  # all but ID and baud rate
    assert any_ph.read4ByteTxRx(port, 2, HOMING_OFFSET) == (0, COMM_SUCCESS, 0)


def test_clear_multi_turn(bus, port, ph) -> None:
    ok(ph.write1ByteTxRx(port, 1, OPERATING_MODE, OperatingMode.EXTENDED_POSITION))
    with bus.lock:
        bus.plant.set_state([2 * 2 * np.pi + 0.1, 0.0])  # two turns and a bit
        bus.advance(0.002)
    assert ph.read4ByteTxRx(port, 1, PRESENT_POS)[0] > 2 * 4096
    ok(ph.clearMultiTurn(port, 1))
    assert 0 <= ph.read4ByteTxRx(port, 1, PRESENT_POS)[0] < 4096


# -- error handling ------------------------------------------------------------------------


def test_undefined_or_misaddressed_instruction_gets_instruction_error(bus, port) -> None:
    rx, result = raw_transaction(port, build_instruction(1, 0x42))
    assert result == COMM_SUCCESS and rx[8] == StatusError.INSTRUCTION
    sync_read_to_one = build_instruction(2, Instruction.SYNC_READ, bytes((PRESENT_POS, 0, 4, 0, 2)))
    rx, result = raw_transaction(port, sync_read_to_one)
    assert result == COMM_SUCCESS and rx[4] == 2 and rx[8] == StatusError.INSTRUCTION
    rx, result = raw_transaction(port, build_instruction(BROADCAST_ID, 0x42))
    assert result == COMM_RX_TIMEOUT


def test_corrupted_crc_gets_crc_error_status(bus, port) -> None:
    packet = bytearray(build_instruction(1, Instruction.READ, bytes((PRESENT_POS, 0, 4, 0))))
    packet[-1] ^= 0x5A
    rx, result = raw_transaction(port, bytes(packet))
    assert result == COMM_SUCCESS
    assert rx[4] == 1 and rx[8] == StatusError.CRC
    assert bus.stats.crc_errors == 1


def test_unstuffed_header_is_dropped_and_next_packet_answered(bus, port, ph, stock) -> None:
    ok(stock.write1ByteTxRx(port, 1, OPERATING_MODE, OperatingMode.EXTENDED_POSITION))
    goal = -131073  # FF FF FD FF on the wire
    assert list(u32(goal).to_bytes(4, "little")) == [0xFF, 0xFF, 0xFD, 0xFF]
    # dynamixel-sdk 4.1.0 sends it unstuffed: the servo resyncs on the header and stays silent.
    assert stock.write4ByteTxRx(port, 1, GOAL_POS, u32(goal)) == (COMM_RX_TIMEOUT, 0)
    assert stock.ping(port, 1) == (1020, COMM_SUCCESS, 0)
    assert s32(stock.read4ByteTxRx(port, 1, GOAL_POS)[0]) != goal
    # Stuffed correctly it arrives intact, both ways.
    ok(ph.write4ByteTxRx(port, 1, GOAL_POS, u32(goal)))
    value, result, error = ph.read4ByteTxRx(port, 1, GOAL_POS)
    assert (s32(value), result, error) == (goal, COMM_SUCCESS, 0)
    assert bus.servo(1).get("Goal Position") == goal


def test_values_needing_stuffing_survive_sync_reads(bus, port, ph) -> None:
    servo = bus.servo(1)
    servo.force("Present Current", -1)  # FF FF
    servo.force("Present Velocity", -3)  # FD FF FF FF -> FF FF FD on the wire
    bus.servo(2).force("Present Current", 5)
    reader = GroupSyncRead(port, ph, PRESENT_CURRENT, 6)
    reader.addParam(1)
    reader.addParam(2)
    for read in (reader.txRxPacket, reader.fastSyncRead):
        assert read() == COMM_SUCCESS
        assert reader.getData(1, PRESENT_CURRENT, 2) == 0xFFFF
        assert s32(reader.getData(1, PRESENT_VEL, 4)) == -3
        assert reader.getData(2, PRESENT_CURRENT, 2) == 5


def test_goal_beyond_position_limits_gets_data_limit_error(bus, port, stock) -> None:
    ok(stock.write4ByteTxRx(port, 1, MAX_POS, 3000))
    ok(stock.write1ByteTxRx(port, 1, TORQUE, 1))
    assert stock.write4ByteTxRx(port, 1, GOAL_POS, 3500) == (COMM_SUCCESS, StatusError.DATA_LIMIT)
    ok(stock.write4ByteTxRx(port, 1, GOAL_POS, 2900))
    # A fixed range is a range error: Operating Mode 2 does not exist.
    ok(stock.write1ByteTxRx(port, 1, TORQUE, 0))
    assert stock.write1ByteTxRx(port, 1, OPERATING_MODE, 2) == (COMM_SUCCESS, StatusError.DATA_RANGE)


def test_eeprom_write_with_torque_on_gets_access_error(bus, port, stock) -> None:
    ok(stock.write1ByteTxRx(port, 1, TORQUE, 1))
    assert stock.write4ByteTxRx(port, 1, MAX_POS, 3000) == (COMM_SUCCESS, StatusError.ACCESS)
    assert stock.write4ByteTxRx(port, 1, PRESENT_POS, 0) == (COMM_SUCCESS, StatusError.ACCESS)
    assert stock.write2ByteTxRx(port, 1, GOAL_POS, 100) == (COMM_SUCCESS, StatusError.DATA_LENGTH)


def test_unknown_id_and_broadcast_write_get_no_answer(bus, port, ph) -> None:
    assert ph.ping(port, 99) == (0, COMM_RX_TIMEOUT, 0)
    assert ph.read1ByteTxRx(port, 42, LED) == (0, COMM_RX_TIMEOUT, 0)
    assert ph.write1ByteTxOnly(port, BROADCAST_ID, LED, 1) == COMM_SUCCESS
    port.setPacketTimeoutMillis(60)
    assert port.readPort(11) == b""
    assert bus.servo(1).get("LED") == 1 and bus.servo(2).get("LED") == 1
    assert ph.write1ByteTxRx(port, BROADCAST_ID, LED, 0) == (COMM_SUCCESS, 0)  # SDK does not wait


def test_status_return_level_one_answers_reads_only(bus, port, ph) -> None:
    ok(ph.write1ByteTxRx(port, 1, STATUS_RETURN_LEVEL, 1))
    assert ph.write1ByteTxRx(port, 1, LED, 1)[0] == COMM_RX_TIMEOUT
    assert ph.read1ByteTxRx(port, 1, LED) == (1, COMM_SUCCESS, 0)


def test_overload_shuts_down_until_reboot() -> None:
    plant = InertiaPlant(1, inertia=0.01, viscous=0.02)
    plant.block(0)  # jammed joint
    with make_bus((1,), plant=plant, servo_kwargs={"overload_time_s": 0.3}) as bus:
        port = open_port(bus)
        ph = StuffingPacketHandler()
        ok(ph.write1ByteTxRx(port, 1, TORQUE, 1))
        ok(ph.write4ByteTxRx(port, 1, GOAL_POS, 2048 + 600))
        assert wait_for(lambda: ph.read1ByteTxRx(port, 1, HW_ERROR)[0] == 0x20, timeout=3.0)
        value, result, error = ph.read1ByteTxRx(port, 1, TORQUE)
        assert (value, result) == (0, COMM_SUCCESS)
        assert error == ALERT_BIT  # the alert bit rides on every status packet
        assert ph.ping(port, 1) == (1020, COMM_SUCCESS, ALERT_BIT)
        assert ph.write1ByteTxRx(port, 1, TORQUE, 1) == (
            COMM_SUCCESS,
            StatusError.RESULT_FAIL | ALERT_BIT,
        )
        # REBOOT answers before it reboots, so its own status still carries the alert.
        assert ph.reboot(port, 1) == (COMM_SUCCESS, ALERT_BIT)
        assert ph.read1ByteTxRx(port, 1, HW_ERROR) == (0, COMM_SUCCESS, 0)
        ok(ph.write1ByteTxRx(port, 1, TORQUE, 1))
        port.closePort()


def test_huge_gravity_load_overloads() -> None:
    plant = InertiaPlant(1, inertia=0.01, viscous=0.02, gravity=-8.0)  # twice the stall torque
    with make_bus((1,), plant=plant, servo_kwargs={"overload_time_s": 0.2}) as bus:
        port = open_port(bus)
        ph = StuffingPacketHandler()
        ok(ph.write1ByteTxRx(port, 1, TORQUE, 1))
        assert wait_for(lambda: ph.read1ByteTxRx(port, 1, HW_ERROR)[0] & 0x20 != 0, timeout=3.0)
        assert not bus.servo(1).torque_enabled
        port.closePort()


def test_scan_at_several_bauds_finds_servos_at_their_own_rate() -> None:
    servos = {
        1: ServoModel(XM430_W350, registers=FAST),
        7: ServoModel(XL430_W250, registers={"Baud Rate": 1}),  # 57600, the factory rate
    }
    with DynamixelBusEmulator(servos, InertiaPlant(2)) as bus:
        ph = StuffingPacketHandler()
        port = open_port(bus, 1_000_000)
        assert bus.host_baud() == 1_000_000
        assert ph.ping(port, 1)[1] == COMM_SUCCESS
        assert ph.ping(port, 7)[1] == COMM_RX_TIMEOUT
        assert port.setBaudRate(57_600)
        assert ph.ping(port, 7) == (1060, COMM_SUCCESS, 0)
        assert ph.ping(port, 1)[1] == COMM_RX_TIMEOUT
        port.closePort()


def test_all_servos_listen_when_the_port_speed_is_unknown() -> None:
    servos = {3: ServoModel(XM430_W350, registers={"Baud Rate": 1})}
    with DynamixelBusEmulator(servos, InertiaPlant(1)) as bus:
        port = open_port(bus, 1_000_000)
        ph = StuffingPacketHandler()
        assert ph.ping(port, 3)[1] == COMM_RX_TIMEOUT
        bus.host_baud = lambda: None  # e.g. a platform where the speed cannot be read back
        assert ph.ping(port, 3)[1] == COMM_SUCCESS
        port.closePort()


def test_fast_sync_read_with_a_silent_servo_comes_out_short(bus, port, ph) -> None:
    reader = GroupSyncRead(port, ph, PRESENT_POS, 4)
    reader.addParam(1)
    reader.addParam(2)
    bus.faults.silent_ids = {2}
    assert reader.fastSyncRead() == COMM_RX_CORRUPT  # LEN promised two blocks, one came
    assert reader.txRxPacket() == COMM_RX_TIMEOUT  # plain sync read: ID 2 never answers
    bus.faults.silent_ids = set()
    assert reader.fastSyncRead() == COMM_SUCCESS


# -- motion ------------------------------------------------------------------------------------


def test_goal_reached_and_loaded_joint_lags() -> None:
    plant = InertiaPlant(2, inertia=0.02, viscous=0.02, gravity=[0.0, -2.0])
    with make_bus((1, 2), plant=plant) as bus:
        port = open_port(bus)
        ph = StuffingPacketHandler()
        with bus.lock:
            start = [bus.servo(1).get("Present Position"), bus.servo(2).get("Present Position")]
        for i in (1, 2):
            ok(ph.write1ByteTxRx(port, i, TORQUE, 1))
        time.sleep(0.3)  # the loaded joint settles under its load first
        hold = [s32(ph.read4ByteTxRx(port, i, PRESENT_POS)[0]) for i in (1, 2)]
        goals = [h + 400 for h in hold]
        for i, goal in zip((1, 2), goals):
            ok(ph.write4ByteTxRx(port, i, GOAL_POS, goal))
        time.sleep(0.12)
        mid = [s32(ph.read4ByteTxRx(port, i, PRESENT_POS)[0]) for i in (1, 2)]
        time.sleep(0.9)
        final = [s32(ph.read4ByteTxRx(port, i, PRESENT_POS)[0]) for i in (1, 2)]
        error = [goal - pos for goal, pos in zip(goals, final)]
        assert abs(error[0]) <= 3, f"light joint ended {error[0]} ticks from its goal"
        assert error[1] > abs(error[0]) + 20, f"loaded joint error {error[1]} ticks"
        assert mid[0] - hold[0] > mid[1] - hold[1] + 20, f"progress after 0.12 s: {mid} from {hold}"
        assert start[1] - hold[1] > 20  # it sagged under the load when torque came on
        assert ph.read1ByteTxRx(port, 1, MOVING)[0] == 0
        port.closePort()


def test_profile_velocity_paces_the_move(bus, port, ph) -> None:
    ok(ph.write4ByteTxRx(port, 1, PROFILE_VEL, 100))  # 22.9 rev/min = 2.40 rad/s
    ok(ph.write1ByteTxRx(port, 1, TORQUE, 1))
    t0 = time.monotonic()
    ok(ph.write4ByteTxRx(port, 1, GOAL_POS, 2048 + 512))  # 0.785 rad -> ~0.33 s
    time.sleep(0.15)
    assert ph.read1ByteTxRx(port, 1, MOVING)[0] == 1
    assert 2048 + 100 < ph.read4ByteTxRx(port, 1, 140)[0] < 2048 + 420  # Position Trajectory
    assert wait_for(lambda: ph.read1ByteTxRx(port, 1, MOVING)[0] == 0, timeout=2.0)
    assert time.monotonic() - t0 > 0.3
    assert wait_for(lambda: abs(ph.read4ByteTxRx(port, 1, PRESENT_POS)[0] - 2560) <= 3, timeout=1.0)


def test_id_change_answers_with_the_old_id(bus, port, ph) -> None:
    ok(ph.write1ByteTxRx(port, 1, 7, 5))  # ID(7) = 5
    assert ph.ping(port, 5) == (1020, COMM_SUCCESS, 0)
    assert ph.ping(port, 1)[1] == COMM_RX_TIMEOUT
    assert sorted(bus.servos) == [2, 5]


def test_homing_offset_shifts_present_position(bus, port, ph) -> None:
    before = s32(ph.read4ByteTxRx(port, 1, PRESENT_POS)[0])
    ok(ph.write4ByteTxRx(port, 1, HOMING_OFFSET, u32(-1000)))
    assert s32(ph.read4ByteTxRx(port, 1, PRESENT_POS)[0]) == before - 1000


def test_deadband_stops_correcting_near_the_goal() -> None:
    plant = InertiaPlant(1, inertia=0.01, viscous=0.02, coulomb=0.05)
    with make_bus((1,), plant=plant, servo_kwargs={"deadband_ticks": 40}) as bus:
        port = open_port(bus)
        ph = StuffingPacketHandler()
        ok(ph.write1ByteTxRx(port, 1, TORQUE, 1))
        ok(ph.write4ByteTxRx(port, 1, GOAL_POS, 2048 + 400))
        assert wait_for(lambda: ph.read1ByteTxRx(port, 1, MOVING)[0] == 0 and
                        abs(ph.read4ByteTxRx(port, 1, PRESENT_POS)[0] - 2448) <= 40, timeout=3.0)
        time.sleep(0.1)
        error = 2448 - ph.read4ByteTxRx(port, 1, PRESENT_POS)[0]
        assert 3 < abs(error) <= 41
        assert ph.read2ByteTxRx(port, 1, 124)[0] == 0  # Present PWM: not correcting
        port.closePort()


# -- faults and timing ------------------------------------------------------------------------


def test_fault_hooks(bus, port, ph) -> None:
    bus.faults.drop_prob = 1.0
    assert ph.ping(port, 1)[1] == COMM_RX_TIMEOUT
    bus.faults.drop_prob = 0.0
    bus.faults.corrupt_crc_prob = 1.0
    assert ph.ping(port, 1)[1] == COMM_RX_CORRUPT
    bus.faults.corrupt_crc_prob = 0.0
    bus.faults.silent_ids = {2}
    assert ph.ping(port, 1)[1] == COMM_SUCCESS and ph.ping(port, 2)[1] == COMM_RX_TIMEOUT
    bus.faults.silent_ids = set()
    bus.faults.delay_s = 0.01
    t0 = time.monotonic()
    assert ph.ping(port, 2)[1] == COMM_SUCCESS and time.monotonic() - t0 >= 0.01
    bus.faults.delay_s = 0.0

    bus.unplug()
    assert ph.write1ByteTxRx(port, 1, LED, 1)[0] == COMM_RX_TIMEOUT
    assert bus.servo(1).get("LED") == 0  # nothing heard, nothing done
    bus.replug()
    ok(ph.write1ByteTxRx(port, 1, LED, 1))
    bus.faults.hook = lambda servo_id, packet: None if servo_id == 1 else packet
    assert ph.ping(port, 1)[1] == COMM_RX_TIMEOUT and ph.ping(port, 2)[1] == COMM_SUCCESS


def test_random_drops_are_seeded() -> None:
    def run() -> list[int]:
        with make_bus((1,), seed=42) as bus:
            bus.faults.drop_prob = 0.5
            port = open_port(bus)
            ph = StuffingPacketHandler()
            outcome = [ph.ping(port, 1)[1] for _ in range(12)]
            port.closePort()
            return outcome

    first = run()
    assert first == run()
    assert COMM_SUCCESS in first and COMM_RX_TIMEOUT in first


def test_wire_timing_adds_return_delay_and_transfer_time() -> None:
    ph = StuffingPacketHandler()
    with make_bus((1,), registers={"Return Delay Time": 250}, wire_timing=True) as slow_bus, \
            make_bus((1,), registers={"Return Delay Time": 250}, wire_timing=False) as fast_bus:
        ports = {True: open_port(slow_bus), False: open_port(fast_bus)}
        times: dict[bool, list[float]] = {True: [], False: []}
        for wire in (True, False):
            ph.ping(ports[wire], 1)
        for _ in range(30):  # interleaved, so a busy moment of the machine falls on both alike
            for wire in (True, False):
                t0 = time.perf_counter()
                assert ph.ping(ports[wire], 1)[1] == COMM_SUCCESS
                times[wire].append(time.perf_counter() - t0)
        for port in ports.values():
            port.closePort()
    # delays only add (a loaded machine stretches a round trip, never shortens it): the fastest
    # round trip is the cleanest; the exact figure is the virtual clock's (the test below)
    delayed, plain = min(times[True]), min(times[False])
    # 500 us return delay + 14 bytes at 1 Mbps = 640 us on top of the pty round trip.
    assert delayed >= 0.00064
    assert delayed > plain


def test_wire_timing_on_the_virtual_clock_is_the_return_delay_and_both_packets_transfer_exactly() -> None:
    """A ping's round trip on the line's own time: its 10 bytes to the servo, the servo's Return
    Delay Time (250 × 2 us) and its 14-byte status back, at 1 Mbps (10 bits a byte): 740 us."""
    from drivers.clock import VirtualClock
    from drivers.emulator.virtual import VirtualBusEmulator

    clock = VirtualClock()
    servo = ServoModel(XM430_W350, id=1, registers={**FAST, "Return Delay Time": 250})
    with VirtualBusEmulator({1: servo}, clock=clock, name="rdt") as bus:
        port = BlockingPortHandler(bus.port)
        assert port.openPort() and port.setBaudRate(BAUD)
        try:
            ph = StuffingPacketHandler()
            trips = []
            for _ in range(3):
                t0 = clock.now()
                assert ph.ping(port, 1)[1] == COMM_SUCCESS
                trips.append(clock.now() - t0)
        finally:
            port.closePort()
    assert trips == pytest.approx([(10 + 14) * 10 / 1_000_000 + 250 * 2e-6] * 3, abs=1e-9)


@pytest.mark.parametrize("mode", [3, 4])  # position, extended position
def test_goal_position_writes_answer_as_the_general_write_path_does(mode):
    """The cycle's Goal Position writes take a short path; it must accept and refuse alike."""
    servo = ServoModel(XM430_W350, registers={"Operating Mode": mode, "Min Position Limit": 1000,
                                              "Max Position Limit": 3000})
    servo.set("Torque Enable", 1)
    for value in (-1_048_576, -1_048_575, -5, 999, 1000, 2048, 3000, 3001, 1_048_575, 1_048_576):
        data = value.to_bytes(4, "little", signed=True)
        expected = servo.check_write(116, data)  # the general validation
        assert servo.write(116, data) == expected, value
        if expected == 0:
            assert servo.get("Goal Position") == value
    assert servo.write(116, (3001).to_bytes(4, "little")) == (StatusError.DATA_LIMIT if mode == 3 else 0)


def test_the_emulator_reports_the_physics_it_could_not_keep_up_with():
    """A rig starved of CPU (here: stopped for a second) counts what it skipped, and says so."""
    import os
    import signal as _signal
    import time as _time
    from pathlib import Path as _Path

    from bench.rig.emulated import EmulatorProcess

    lab = _Path(__file__).resolve().parent.parent / "hil_configs" / "lab_real.yaml"
    rig = EmulatorProcess(lab)
    try:
        os.kill(rig.proc.pid, _signal.SIGSTOP)
        _time.sleep(1.2)
        os.kill(rig.proc.pid, _signal.SIGCONT)
        _time.sleep(0.3)
    finally:
        rig.close()
    assert rig.stats["physics_steps"] > 0
    assert 0.4 < rig.stats["physics_skipped_s"] < 1.5


def test_an_idle_bus_rests_its_physics_and_a_write_wakes_it():
    """Nothing commanded, servos still: the physics pauses; the next write moves the servo at once."""
    plant = InertiaPlant(1, inertia=0.01, viscous=0.02)
    with make_bus((1,), plant=plant, rest_after_s=0.2) as bus:
        port = open_port(bus)
        ph = StuffingPacketHandler()
        ok(ph.write1ByteTxRx(port, 1, TORQUE, 1))
        assert wait_for(lambda: bus._resting, timeout=3.0), "a still servo must let the physics rest"
        with bus.lock:
            steps = bus.stats.physics_steps
        time.sleep(0.3)
        start = s32(ph.read4ByteTxRx(port, 1, PRESENT_POS)[0])  # reads do not wake it
        with bus.lock:
            assert bus.stats.physics_steps == steps
        ok(ph.write4ByteTxRx(port, 1, GOAL_POS, start + 300))
        assert wait_for(lambda: abs(s32(ph.read4ByteTxRx(port, 1, PRESENT_POS)[0]) - start - 300) <= 3,
                        timeout=2.0), "the write must wake the physics and the servo reach its goal"
        with bus.lock:
            assert bus.stats.rest_s >= 0.3
            assert bus.stats.physics_skipped_s < 0.05  # the rest is not a backlog
        port.closePort()


def test_hilbench_emulate_idles_below_a_tenth_of_a_core():
    """The emulated rig left alone (servos holding, nothing written) costs next to no CPU."""
    import json
    import os
    import signal as _signal
    import subprocess
    import sys
    from pathlib import Path as _Path

    repo = _Path(__file__).resolve().parent.parent
    exe = _Path(sys.executable).with_name("hilbench")
    proc = subprocess.Popen([str(exe), "emulate", str(repo / "hil_configs" / "lab_real.yaml"),
                             "--json"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)

    def cpu_s() -> float:
        fields = _Path(f"/proc/{proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    try:
        json.loads(proc.stdout.readline())
        time.sleep(2.0)  # start-up, the servos settling under gravity, the rest beginning
        c0, t0 = cpu_s(), time.monotonic()
        time.sleep(3.0)
        share = (cpu_s() - c0) / (time.monotonic() - t0)
    finally:
        proc.send_signal(_signal.SIGTERM)
        proc.wait(10)
    assert share < 0.10, f"the idle emulator took {share:.0%} of a core"


def test_every_emulated_model_keeps_the_drivers_registers_where_the_one_table_says():
    """The host-side drivers read one X-series table (control_table.x_series_table); every
    emulated model must hold the registers they touch at the same address and size."""
    from drivers.dynamixel.control_table import STATE_BLOCK, state_block, x_series_table

    used = ("Model Number", "Firmware Version", "Baud Rate", "Return Delay Time", "Operating Mode",
            "Homing Offset", "Position D Gain", "Position I Gain", "Position P Gain", "Torque Enable",
            "Hardware Error Status", "Profile Acceleration", "Profile Velocity", "Goal Position",
            "Present Velocity", "Present Position", "Present Input Voltage", "Present Temperature")
    table = x_series_table()
    assert state_block() == (table[STATE_BLOCK[0]].address, 10)
    for number in supported_models():
        other = model_spec(number).table
        for name in used:
            assert (other[name].address, other[name].size) == (table[name].address, table[name].size), \
                (number, name)
        first = other.at(state_block()[0])  # Present Current, or Present Load without current sensing
        assert first is not None and first.size == 2


def test_an_instruction_arriving_while_the_physics_catches_up_is_answered_within_a_slice():
    """After the emulator was held up (a loaded machine: 0.4 s here), its physics has a backlog to
    catch up; a PING arriving meanwhile is answered after at most a slice of steps, not after the
    backlog (400 steps of a plant costing 0.1 ms a step: 40 ms before it was sliced)."""
    from drivers.emulator.clock import SLICE_STEPS

    class HeavyPlant(InertiaPlant):
        def step(self, dt, torque):
            end = time.perf_counter() + 1e-4  # a heavy physics engine's step
            while time.perf_counter() < end:
                pass
            super().step(dt, torque)

    with DynamixelBusEmulator({1: ServoModel(registers=FAST)}, HeavyPlant(1)) as bus:
        port = open_port(bus)
        try:
            ping = build_instruction(1, Instruction.PING)
            assert raw_transaction(port, ping)[1] == COMM_SUCCESS
            waits = []
            for _ in range(3):
                with bus.lock:  # the serving thread held up; the physics falls 0.4 s behind
                    time.sleep(0.4)
                time.sleep(0.002)  # the catch-up has begun
                t0 = time.perf_counter()
                rx, result = raw_transaction(port, ping, timeout_ms=200.0)
                waits.append(time.perf_counter() - t0)
                assert result == COMM_SUCCESS
        finally:
            port.closePort()
    # the best of three (a loaded machine may hold up one answer for reasons of its own)
    assert min(waits) < 0.01, f"answers took {[f'{1e3 * w:.1f} ms' for w in waits]} behind the backlog"
    assert SLICE_STEPS * 1e-4 < 0.01


def test_a_state_read_after_the_emulator_was_held_up_answers_the_state_now():
    """A servo swinging its load to a far goal; the emulator held up 20 ms: the next Present Position
    is where the shaft is now (within a few ticks), not where it was before the hold-up (tens of
    ticks behind): the steps due run before a state read is answered."""
    with DynamixelBusEmulator({1: ServoModel(registers=FAST)}, InertiaPlant(1, inertia=0.01)) as bus:
        port = open_port(bus)
        handler = StuffingPacketHandler()
        tick = 2 * np.pi / 4096
        try:
            seen = []
            for goal in (4000, 100, 4000):
                assert handler.write1ByteTxRx(port, 1, TORQUE, 1)[0] == COMM_SUCCESS
                assert handler.write4ByteTxRx(port, 1, GOAL_POS, goal)[0] == COMM_SUCCESS
                time.sleep(0.1)  # under way
                before, result, _ = handler.read4ByteTxRx(port, 1, PRESENT_POS)
                with bus.lock:  # the serving thread held up
                    time.sleep(0.02)
                answered, result, _ = handler.read4ByteTxRx(port, 1, PRESENT_POS)
                assert result == COMM_SUCCESS
                with bus.lock:  # where the shaft is (the steps due since run after the answer)
                    now = float(bus.plant.position()[0]) / tick + 2048
                seen.append((abs(s32(answered) - s32(before)), abs(s32(answered) - now)))
                time.sleep(0.5)  # at its goal
        finally:
            port.closePort()
    assert all(moved > 30 for moved, _ in seen), seen  # the hold-up was worth tens of ticks
    # the best of three (a loaded machine may hold the serving thread up again on its own): the
    # answer is a fifth of the hold-up's motion from the shaft at most. Running the 20 steps due
    # takes the emulator a few milliseconds of its own, and the steps falling due meanwhile run
    # after the answer: 2 to 4 steps at this swing (about 3 ticks a step, 6-12 ticks measured on this
    # machine, the same before the virtual clock came); a read answered before the steps due would
    # trail by the hold-up's whole motion, tens of ticks.
    assert min(off for _, off in seen) <= max(5.0, min(moved for moved, _ in seen) / 5), seen
