"""The C37.118.2-2011 codec (nni_msgs_adapter.c37118.frames): round trips, and golden bytes both ways with pyc37.

pyc37 (synchrophasor 1.0.0a's codec) is written independently of ours: it
decodes the frames we write, and we decode the frames it writes, including
layouts we never write ourselves (several stations of different FORMATs,
integer phasors, version 1). Pure: no sockets, no ROS.
"""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from numpy.testing import assert_allclose, assert_array_equal
from pyc37.frame import CommandFrame as PyCommand
from pyc37.frame import CommonFrame as PyFrame
from pyc37.frame import ConfigFrame2 as PyConfig2
from pyc37.frame import DataFrame as PyData
from pyc37.frame import HeaderFrame as PyHeader
from pyc37.utils import crc16xmodem

from c37118_cases import EPOCH_NS, PYC37_FORMAT, plant_config, plant_values, wrapped
from nni_msgs_adapter.c37118 import frames as c37

# --- CRC, time, rates, STAT ---------------------------------------------------------------------


def test_chk_is_crc_ccitt_from_0xffff():
    """The catalogue check value of CRC-16/CCITT-FALSE, and pyc37's own table-driven CRC, agree with ours."""
    assert c37.crc_ccitt(b"123456789") == 0x29B1
    data = bytes(range(256)) * 3
    assert c37.crc_ccitt(data) == crc16xmodem(data, 0xFFFF)


@pytest.mark.parametrize("time_base", [1_000_000, 16_777_215, 600, 1])
@given(instant=st.integers(0, (1 << 32) * 10**9 - 10**9))
def test_instant_round_trips_to_the_nearest_unit_of_the_time_base(time_base, instant):
    soc, fraction = c37.split_instant_ns(instant, time_base)
    assert 0 <= fraction < time_base
    back = c37.instant_ns_from(soc, fraction, time_base)
    assert abs(back - instant) <= 10**9 / (2 * time_base) + 1


def test_instants_round_half_up_and_roll_over_to_the_next_second():
    assert c37.split_instant_ns(EPOCH_NS + 499, 1_000_000) == (1_700_000_000, 0)
    assert c37.split_instant_ns(EPOCH_NS + 500, 1_000_000) == (1_700_000_000, 1)
    assert c37.split_instant_ns(EPOCH_NS - 400, 1_000_000) == (1_700_000_000, 0)
    assert c37.split_instant_ns(EPOCH_NS + 20_000_000, 1_000_000) == (1_700_000_000, 20_000)


def test_a_time_base_multiple_of_600_stamps_every_allowed_rate_exactly():
    for rates in c37.ALLOWED_REPORTING_RATES.values():
        for rate in rates:
            for k in range(rate + 1):
                instant = EPOCH_NS + k * 10**9 // rate
                if k * 10**9 % rate == 0:
                    assert c37.instant_ns_from(*c37.split_instant_ns(instant, 600 * 20), 600 * 20) == instant


@pytest.mark.parametrize("bad", [-1_000_000, (1 << 32) * 10**9])
def test_instants_outside_soc_are_refused(bad):
    with pytest.raises(ValueError, match="SOC"):
        c37.split_instant_ns(bad, 1_000_000)


@pytest.mark.parametrize("nominal, rates", sorted(c37.ALLOWED_REPORTING_RATES.items()))
def test_reporting_rates(nominal, rates):
    for rate in rates:
        assert c37.check_reporting_rate(rate, nominal) == rate
    for rate in (1, 5, 24, 30 if nominal == 50 else 25, 200):
        with pytest.raises(ValueError, match=", ".join(map(str, rates))):
            c37.check_reporting_rate(rate, nominal)
    with pytest.raises(ValueError, match="50 or 60"):
        c37.check_reporting_rate(50, 55)


def test_stat_bits_sit_where_the_standard_puts_them():
    assert c37.Stat(data_error=c37.DATA_TEST_MODE).word == 0b10 << 14
    assert c37.Stat(sync_lost=True).word == 1 << 13
    assert c37.Stat(sorted_by_arrival=True).word == 1 << 12
    assert c37.Stat(trigger=True, trigger_reason=c37.TRIGGER_ROCOF).word == 1 << 11 | 5
    assert c37.Stat(config_changed=True).word == 1 << 10
    assert c37.Stat(data_modified=True).word == 1 << 9
    assert c37.Stat(pmu_time_quality=c37.PMU_TIME_QUALITY_UNKNOWN).word == 0b111 << 6
    assert c37.Stat(unlocked_time=3).word == 0b11 << 4
    assert not c37.Stat(data_error=c37.DATA_PMU_ERROR).data_valid and c37.Stat().data_valid


@given(st.integers(0, 0xFFFF))
def test_stat_word_round_trips(word):
    assert c37.Stat.from_word(word).word == word


def test_stat_fields_are_range_checked():
    with pytest.raises(ValueError, match="trigger_reason"):
        c37.Stat(trigger_reason=16)


def test_time_quality_byte():
    assert c37.time_quality_byte(0xB, leap_second_pending=True, leap_second_deleted=True) == 0x5B
    with pytest.raises(ValueError, match="time quality"):
        c37.time_quality_byte(16)


# --- round trips ------------------------------------------------------------------------------------

ALL_FORMATS = [c37.DataFormat.from_word(word) for word in range(16)]


@pytest.mark.parametrize("frame_type", c37.CONFIG_TYPES)
def test_configuration_frames_round_trip(frame_type):
    config = plant_config(4)
    frame = c37.encode_config(config, frame_type, EPOCH_NS)
    decoded = c37.decode_config(frame)
    assert decoded.head.frame_type == frame_type and decoded.head.version == c37.VERSION_2011
    assert decoded.config == config
    assert decoded.head.framesize == len(frame)


def test_cfg3_carries_long_names_and_the_fields_cfg2_lacks():
    station = c37.Station("Generator 12 at bus 35, Kundur ring (a name past 16 bytes)", 12,
                          (c37.PhasorChannel("internal EMF E' of generator 12", component=c37.PHASE_A),),
                          global_pmu_id=bytes(range(16)), latitude_deg=47.5, longitude_deg=8.25,
                          elevation_m=410.0, service_class="M", window_us=40_000, group_delay_us=-20_000)
    config = c37.Config(9, (station,), 25)
    assert c37.decode_config(c37.encode_config(config, c37.FrameType.CFG3, EPOCH_NS)).config == config
    cfg2 = c37.decode_config(c37.encode_config(config, c37.FrameType.CFG2, EPOCH_NS)).config.stations[0]
    assert cfg2.name == "Generator 12 at" and cfg2.phasors[0].name == "internal EMF E'"


@pytest.mark.parametrize("data_format", ALL_FORMATS, ids=lambda f: f"format{f.word}")
def test_data_frames_round_trip_in_every_format(data_format):
    phasors = tuple(c37.PhasorChannel(name, scale=20) for name in ("E", "V"))
    stations = tuple(c37.Station(f"S{k}", k, phasors, (c37.AnalogChannel("A"),), (), data_format, 60)
                     for k in (1, 2))
    config = c37.Config(3, stations, 30)
    values = c37.Measurements(stat=[0, 0x0800], magnitude=[[0.5, 0.25], [0.1, 0.6]],
                              angle_rad=[[0.5, -3.0], [2.0, 7.0]], frequency_hz=[60.012, 59.9],
                              rocof_hz_per_s=[0.25, -1.5], analog=[[12.0], [-7.0]], digital=0)
    frame = c37.DataFrameEncoder(config).encode(EPOCH_NS + 33_333_333, values)
    decoded = c37.DataFrameDecoder(config).decode(frame)
    assert decoded.instant_ns == EPOCH_NS + 33_333_000
    assert [s.stat for s in decoded.stations] == [0, 0x0800]
    magnitude = np.array([s.magnitudes for s in decoded.stations])
    angle = np.array([s.angles_rad for s in decoded.stations])
    # Integer phasors: 16 bits of 20e-5 per bit (rectangular: per component), angles 1e-4 rad.
    magnitude_tol = 1e-6 if data_format.phasor_float else 20e-5
    angle_tol = 1e-6 if data_format.phasor_float else (1e-4 if data_format.polar else 2e-3)
    assert_allclose(magnitude, values.magnitude, atol=magnitude_tol)
    assert_allclose(np.cos(angle - np.asarray(values.angle_rad)), 1.0, atol=angle_tol)
    freq_tol = 1e-5 if data_format.freq_float else 5e-4
    assert_allclose([s.frequency_hz for s in decoded.stations], values.frequency_hz, atol=freq_tol)
    assert_allclose([s.rocof_hz_per_s for s in decoded.stations], values.rocof_hz_per_s,
                    atol=1e-6 if data_format.freq_float else 5e-3)
    assert_allclose([s.analogs[0] for s in decoded.stations], [12.0, -7.0])


def test_float_polar_angles_go_out_wrapped_into_minus_pi_pi():
    config = plant_config(3)
    values = plant_values(3, 60)
    decoded = c37.DataFrameDecoder(config).decode(c37.DataFrameEncoder(config).encode(EPOCH_NS, values))
    angle = np.array([s.angles_rad for s in decoded.stations])
    assert np.all(np.abs(angle) <= math.pi)
    assert_allclose(angle, wrapped(values.angle_rad), atol=4e-7)
    assert np.max(np.abs(np.asarray(values.angle_rad))) > math.pi


def test_integer_values_saturate_rather_than_wrap():
    config = c37.Config(1, (c37.Station("S", 1, (c37.PhasorChannel("E", scale=1),), (c37.AnalogChannel("A"),), (),
                                        c37.DataFormat(True, False, False, False)),), 50)
    values = c37.Measurements(stat=0, magnitude=[[10.0]], angle_rad=[[0.1]], frequency_hz=[90.0],
                              rocof_hz_per_s=[-900.0], analog=[[1e6]])
    (reading,) = c37.DataFrameDecoder(config).decode(c37.DataFrameEncoder(config).encode(EPOCH_NS, values)).stations
    assert reading.magnitudes[0] == pytest.approx(65535e-5)
    assert reading.frequency_hz == pytest.approx(50 + 32.767)
    assert reading.rocof_hz_per_s == pytest.approx(-327.67)
    assert reading.analogs == (32767.0,)


def test_command_and_header_frames_round_trip():
    for command in [*c37.Command, 0x0100]:
        frame = c37.encode_command(7, command, EPOCH_NS, extended=b"\x00\x01" if command == 8 else b"")
        decoded = c37.decode_command(frame, idcode=7)
        assert decoded.command == command and decoded.head.frame_type == c37.FrameType.COMMAND
        assert decoded.extended == (b"\x00\x01" if command == 8 else b"")
    header = c37.decode_header(c37.encode_header(7, "SMIB plant, EMF phasor per generator", EPOCH_NS))
    assert header.text == "SMIB plant, EMF phasor per generator"


def test_the_encoder_wants_one_layout_and_a_frame_that_fits():
    mixed = c37.Config(1, (c37.Station("A", 1, (c37.PhasorChannel("E"),)), c37.Station("B", 2)), 50)
    with pytest.raises(ValueError, match="share one layout"):
        c37.DataFrameEncoder(mixed)
    many = tuple(c37.Station(f"S{k}", k, tuple(c37.PhasorChannel(f"P{j}") for j in range(100))) for k in range(1, 90))
    with pytest.raises(ValueError, match="65535"):
        c37.DataFrameEncoder(c37.Config(1, many, 50))
    with pytest.raises(ValueError, match="65535"):
        c37.encode_config(c37.Config(1, many, 50), c37.FrameType.CFG2, EPOCH_NS)


@pytest.mark.parametrize("make, match", [
    (lambda: c37.Config(0, (c37.Station("A", 1),), 50), "IDCODE"),
    (lambda: c37.Config(1, (), 50), "1 to 65535 stations"),
    (lambda: c37.Config(1, (c37.Station("A", 1),), 0), "DATA_RATE"),
    (lambda: c37.Config(1, (c37.Station("A", 1),), 50, time_base=1 << 24), "TIME_BASE"),
    (lambda: c37.Station("A", 1, nominal_hz=55), "50 or 60"),
    (lambda: c37.Station("x" * 256, 1), "255"),
    (lambda: c37.Station("A", 1, service_class="X"), "service class"),
    (lambda: c37.Station("A", 1, (c37.PhasorChannel("E", scale=0),), data_format=c37.DataFormat(phasor_float=False)),
     "PHUNIT scale must be positive"),
    (lambda: c37.PhasorChannel("E", scale=1 << 24), "PHUNIT"),
    (lambda: c37.AnalogChannel("A", scale=1 << 23), "ANUNIT"),
    (lambda: c37.DigitalWord(("b",) * 15), "16 bits"),
])
def test_configurations_say_what_is_wrong(make, match):
    with pytest.raises(ValueError, match=match):
        make()


# --- reading: every refusal has its reason -----------------------------------------------------------


def _recrc(frame: bytearray) -> bytes:
    frame[-2:] = struct.pack(">H", c37.crc_ccitt(bytes(frame[:-2])))
    return bytes(frame)


def _data_frame(config=None, k=0):
    config = config or plant_config(2)
    values = plant_values(len(config.stations), k)
    return config, c37.DataFrameEncoder(config).encode(EPOCH_NS + k * 20_000_000, values)


def _reason(call) -> str:
    with pytest.raises(c37.FrameError) as caught:
        call()
    return caught.value.reason


def test_bad_frames_are_refused_with_their_reason():
    config, frame = _data_frame()
    decoder = c37.DataFrameDecoder(config)
    bad_crc = bytearray(frame)
    bad_crc[20] ^= 0x01
    assert _reason(lambda: decoder.decode(bytes(bad_crc))) == "bad_crc"
    assert _reason(lambda: decoder.decode(frame[:-1])) == "truncated"
    assert _reason(lambda: decoder.decode(frame[:3])) == "truncated"
    assert _reason(lambda: decoder.decode(frame + b"\0")) == "bad_framesize"
    assert _reason(lambda: decoder.decode(b"\xab" + frame[1:])) == "bad_sync"
    assert _reason(lambda: decoder.decode(_recrc(bytearray(b"\xaa\x82" + frame[2:])))) == "bad_sync"
    assert _reason(lambda: decoder.decode(_recrc(bytearray(b"\xaa\x62" + frame[2:])))) == "unknown_type"
    assert _reason(lambda: decoder.decode(_recrc(bytearray(b"\xaa\x03" + frame[2:])))) == "bad_version"
    assert _reason(lambda: decoder.decode(_recrc(bytearray(frame[:4] + b"\x00\x08" + frame[6:])))) == "wrong_idcode"
    assert _reason(lambda: decoder.decode(c37.encode_header(7, "x", EPOCH_NS))) == "wrong_type"
    assert _reason(lambda: c37.read_head(frame, max_frame_bytes=len(frame) - 1)) == "oversized"
    tiny = bytearray(frame[:16])
    tiny[2:4] = b"\x00\x0f"
    assert _reason(lambda: c37.read_head(bytes(tiny))) == "bad_framesize"
    _, smaller = _data_frame(plant_config(1))
    assert _reason(lambda: decoder.decode(_recrc(bytearray(smaller[:4] + frame[4:6] + smaller[6:])))) == \
        "bad_framesize"
    late = bytearray(frame)
    late[11:14] = (1_000_000).to_bytes(3, "big")
    assert _reason(lambda: decoder.decode(_recrc(late))) == "bad_fracsec"


def test_bad_configuration_frames_are_refused():
    frame = bytearray(c37.encode_config(plant_config(2), c37.FrameType.CFG2, EPOCH_NS))
    short = bytearray(frame[:-10] + frame[-2:])
    short[2:4] = struct.pack(">H", len(short))
    assert _reason(lambda: c37.decode_config(_recrc(short))) == "bad_body"
    wrong_fnom = bytearray(frame)
    wrong_fnom[18:20] = b"\x00\x00"  # NUM_PMU 0: stations left over
    assert _reason(lambda: c37.decode_config(_recrc(wrong_fnom))) == "bad_body"
    cfg3 = bytearray(c37.encode_config(plant_config(1), c37.FrameType.CFG3, EPOCH_NS))
    cfg3[14:16] = b"\x00\x01"  # CONT_IDX 1: the first of several frames
    assert _reason(lambda: c37.decode_config(_recrc(cfg3))) == "unsupported"
    assert _reason(lambda: c37.decode_command(c37.encode_config(plant_config(1), c37.FrameType.CFG1, EPOCH_NS))) == \
        "wrong_type"


@given(st.binary(max_size=300))
def test_garbage_only_ever_raises_frame_errors(data):
    decoder = c37.DataFrameDecoder(plant_config(2))
    for read in (decoder.decode, c37.decode_config, c37.decode_command, c37.decode_header):
        for candidate in (data, b"\xaa\x32" + data, _recrc(bytearray(b"\xaa\x32" + len(data).to_bytes(2, "big")
                                                                      + data[4:] + b"\0\0")) if len(data) >= 18
                          else data):
            try:
                read(candidate)
            except c37.FrameError as error:
                assert error.reason in c37.FrameError.REASONS


# --- golden bytes: pyc37 reads ours ---------------------------------------------------------------


def test_pyc37_reads_our_cfg2():
    config = plant_config(3, data_format=PYC37_FORMAT)
    theirs = PyFrame.convert2frame(c37.encode_config(config, c37.FrameType.CFG2, EPOCH_NS + 250_000_000))
    assert isinstance(theirs, PyConfig2)
    assert theirs.get_id_code() == 7 and theirs.get_num_pmu() == 3
    assert [name.rstrip() for name in theirs.get_station_name()] == [s.name for s in config.stations]
    assert theirs.get_stream_id_code() == [101, 102, 103]
    assert theirs.get_data_format() == [(True, True, True, False)] * 3
    assert theirs.get_phasor_num() == [3, 3, 3] and theirs.get_analog_num() == [1, 1, 1]
    assert theirs.get_ph_units()[0] == [(1, "v"), (1, "v"), (1, "i")]
    assert theirs.get_fnom() == [50, 50, 50] and theirs.get_cfg_count() == [1, 1, 1]
    assert theirs.get_data_rate() == 50 and theirs.get_time_base() == 1_000_000
    assert theirs.get_soc() == 1_700_000_000 and theirs.get_frasec()[0] == 250_000
    assert [name.rstrip() for name in theirs.get_channel_names()[0][:4]] == ["EMF E'", "V terminal", "I terminal",
                                                                            "P battery pu"]


@pytest.mark.parametrize("k", [0, 17, 61])
def test_pyc37_reads_our_data_frames(k):
    config = plant_config(3, data_format=PYC37_FORMAT)
    cfg = PyFrame.convert2frame(c37.encode_config(config, c37.FrameType.CFG2, EPOCH_NS))
    values = plant_values(3, k)
    instant = EPOCH_NS + k * 20_000_000
    theirs = PyFrame.convert2frame(c37.DataFrameEncoder(config).encode(instant, values), cfg)
    assert isinstance(theirs, PyData)
    decoded = theirs.get_measurements()
    assert decoded["pmu_id"] == 7 and decoded["time"] == pytest.approx(instant / 1e9, abs=1e-6)
    for row, station in enumerate(decoded["measurements"]):
        assert station["stat"] == "ok"
        phasors = np.array(station["phasors"])
        # Float32 on the wire: equal to float32 precision.
        assert_array_equal(phasors[:, 0], np.float32(values.magnitude[row]))
        assert_array_equal(phasors[:, 1], np.float32(wrapped(values.angle_rad[row])))
        assert station["frequency"] == pytest.approx(values.frequency_hz[row], abs=5e-4)
        assert station["analog"] == [np.float32(values.analog[row][0])]
        assert station["digital"] == [values.digital[row][0]]


def test_pyc37_reads_our_commands_and_header():
    for command, word in ((c37.Command.DATA_OFF, "stop"), (c37.Command.DATA_ON, "start"),
                          (c37.Command.SEND_HEADER, "header"), (c37.Command.SEND_CFG1, "cfg1"),
                          (c37.Command.SEND_CFG2, "cfg2"), (c37.Command.SEND_CFG3, "cfg3")):
        theirs = PyFrame.convert2frame(c37.encode_command(7, command, EPOCH_NS))
        assert isinstance(theirs, PyCommand) and theirs.get_command() == word and theirs.get_id_code() == 7
    theirs = PyFrame.convert2frame(c37.encode_header(7, "one SMIB generator", EPOCH_NS))
    assert isinstance(theirs, PyHeader)


# --- golden bytes: we read pyc37's ----------------------------------------------------------------


def _their_two_station_stream():
    """Two stations of different FORMATs: integer polar and float rectangular phasors, 2005 version bits."""
    cfg = PyConfig2(4711, 1_000_000, 2, ["STATION A", "STATION B"], [11, 12],
                    [(True, False, False, False), (False, True, True, False)], [2, 1], [1, 1], [1, 0],
                    [["VA", "IA", "ANALOG", *[f"BIT{b}" for b in range(16)]], ["VB", "ANALOG B"]],
                    [[(915527, "v"), (45776, "i")], [(0, "v")]], [[(1, "rms")], [(1, "pow")]],
                    [[(0x0000, 0xFFFF)], []], [60, 50], [3, 4], 30, soc=1_600_000_000, frasec=(500_000,))
    data = PyData(4711, [0, 0x2000], [[(14635, 1571), (1200, -31416)], [(0.5, -0.5)]], [125, -40], [30, -7],
                  [[100], [0.25]], [[0x0005], []], cfg, soc=1_600_000_001, frasec=(250_000,))
    return cfg.convert2bytes(), data.convert2bytes()


def test_we_read_pyc37s_configuration():
    cfg_bytes, _ = _their_two_station_stream()
    frame = c37.decode_config(cfg_bytes, idcode=4711)
    assert frame.head.version == 1 and frame.head.frame_type == c37.FrameType.CFG2
    config = frame.config
    assert config.time_base == 1_000_000 and config.data_rate == 30
    a, b = config.stations
    assert (a.name, a.idcode, b.name, b.idcode) == ("STATION A", 11, "STATION B", 12)
    assert a.data_format == c37.DataFormat(True, False, False, False)
    assert b.data_format == c37.DataFormat(False, True, True, False)
    assert [(p.name, p.is_current, p.scale) for p in a.phasors] == [("VA", False, 915527), ("IA", True, 45776)]
    assert a.analogs == (c37.AnalogChannel("ANALOG", c37.ANALOG_RMS, 1),)
    assert b.analogs == (c37.AnalogChannel("ANALOG B", c37.ANALOG_POINT_ON_WAVE, 1),)
    assert a.digitals[0].bit_names[15] == "BIT15" and a.digitals[0].valid_mask == 0xFFFF
    assert (a.nominal_hz, a.config_count, b.nominal_hz, b.config_count) == (60, 3, 50, 4)


def test_we_read_pyc37s_data_frame():
    cfg_bytes, data_bytes = _their_two_station_stream()
    config = c37.decode_config(cfg_bytes).config
    frame = c37.DataFrameDecoder(config).decode(data_bytes)
    assert frame.instant_ns == 1_600_000_001_250_000_000
    a, b = frame.stations
    assert (a.stat, b.stat) == (0, 0x2000)
    assert_allclose(a.magnitudes, [14635 * 915527e-5, 1200 * 45776e-5])
    assert_allclose(a.angles_rad, [0.1571, -3.1416])
    assert a.frequency_hz == pytest.approx(60.125) and a.rocof_hz_per_s == pytest.approx(0.30)
    assert a.analogs == (100.0,) and a.digitals == (5,)
    assert b.magnitudes[0] == pytest.approx(math.hypot(0.5, 0.5))
    assert b.angles_rad[0] == pytest.approx(-math.pi / 4)
    assert b.frequency_hz == pytest.approx(49.96) and b.rocof_hz_per_s == pytest.approx(-0.07)
    assert b.analogs == (0.25,) and b.digitals == ()


def test_we_read_pyc37s_commands_and_header():
    for word, command in (("stop", 1), ("start", 2), ("header", 3), ("cfg1", 4), ("cfg2", 5), ("cfg3", 6)):
        decoded = c37.decode_command(PyCommand(7, word, soc=1_600_000_000, frasec=(1,)).convert2bytes(), idcode=7)
        assert decoded.command == command
    header = PyHeader(7, "Hello from pyc37", soc=1_600_000_000, frasec=(1,)).convert2bytes()
    assert c37.decode_header(header).text == "Hello from pyc37"
