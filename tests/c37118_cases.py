"""Streams the C37.118 tests share: a plant-like configuration and its samples, and pyc37, the independent codec.

``pyc37`` (synchrophasor 1.0.0a's code in the fork that runs on Python 3.10+)
reaches for ``collections.abc`` through ``import collections`` alone, which
works only once something has imported ``collections.abc``: this module
does, before importing it.
"""

from __future__ import annotations

import collections.abc  # noqa: F401  (pyc37.frame needs it loaded; see the module docstring)

import numpy as np

from nni_msgs_adapter.c37118 import frames as c37

#: 2023-11-14 22:13:20 UTC and a fraction: an instant well inside SOC's range.
EPOCH_NS = 1_700_000_000_000_000_000
#: pyc37 reads float FREQ as a deviation in mHz and refuses an actual frequency of 50 Hz (its bug): the
#: streams it judges carry FREQ/DFREQ as integers, which it reads right.
PYC37_FORMAT = c37.DataFormat(polar=True, phasor_float=True, analog_float=True, freq_float=False)


def plant_config(n_stations: int = 3, *, data_format: c37.DataFormat = c37.DataFormat(), idcode: int = 7,
                 rate: int = 50) -> c37.Config:
    """A plant's stream: one station per generator, EMF, terminal voltage and current, one battery analog."""
    stations = tuple(
        c37.Station(f"G{k} bus {30 + k}", 100 + k,
                    (c37.PhasorChannel("EMF E'"), c37.PhasorChannel("V terminal"),
                     c37.PhasorChannel("I terminal", is_current=True)),
                    (c37.AnalogChannel("P battery pu"),),
                    (c37.DigitalWord(tuple(f"bit {b}" for b in range(16))),),
                    data_format, 50, 1)
        for k in range(1, n_stations + 1))
    return c37.Config(idcode, stations, rate)


def plant_values(n_stations: int, k: int, *, stat: int = 0) -> c37.Measurements:
    """Sample k of a swinging plant: angles that grow with k (beyond pi, to exercise the wrapping)."""
    station = np.arange(n_stations)
    return c37.Measurements(
        stat=np.full(n_stations, stat),
        magnitude=np.column_stack([1.05 + 0.01 * station, np.full(n_stations, 1.0), 0.5 + 0.1 * station]),
        angle_rad=np.column_stack([0.3 + 0.07 * k + 0.1 * station, 0.05 * station, -0.2 + 0.0 * station]),
        frequency_hz=50.0 + 0.01 * np.sin(0.1 * k + station),
        rocof_hz_per_s=0.05 * np.cos(0.1 * k + station),
        analog=(0.1 * station)[:, None],
        digital=(station % 2)[:, None])


def data_frame(config: c37.Config, epoch_ns: int, k: int, *, stat=0) -> bytes:
    """Data frame of sample k (stamped ``epoch_ns`` + k periods of 20 ms) of ``config``'s stream."""
    return c37.DataFrameEncoder(config).encode(epoch_ns + k * 20_000_000,
                                                plant_values(len(config.stations), k, stat=stat))


def bad_input_stream(config: c37.Config, epoch_ns: int) -> bytes:
    """Good data frames of ``config``'s stream (a two-station one) around every kind of bad input a PDC must
    reject, one each: bad CRC, wrong sync, another IDCODE, a FRAMESIZE larger than the configuration's,
    a truncated frame, one station's data flagged invalid, time going backwards, a duplicate stamp, a
    command frame from the PMU. Samples 0, 2, 3, 6, 7 (one station) and 8 pass."""
    def data(k: int, **options) -> bytes:
        return data_frame(config, epoch_ns, k, **options)

    damaged = bytearray(data(1))
    damaged[40] ^= 0x10
    other_stream = c37.Config(config.idcode + 1, config.stations, config.data_rate)
    bigger = plant_config(len(config.stations) + 1, idcode=config.idcode)
    bigger_frame = data_frame(bigger, epoch_ns, 4)
    return b"".join([
        data(0),
        bytes(damaged),                                   # bad_crc
        data(2),
        b"\x55\x55",                                      # wrong sync: bad_sync
        data(3),
        data_frame(other_stream, epoch_ns, 0),            # wrong_idcode
        bigger_frame,                                     # bad_framesize: larger than the config's frame
        data(5)[:30], data(6),                            # truncated
        data(7, stat=[0, c37.Stat(data_error=c37.DATA_TEST_MODE).word]),  # invalid_data, one station
        data(5),                                          # time_backwards
        data(7),                                          # duplicate
        c37.encode_command(config.idcode, c37.Command.DATA_ON, epoch_ns),  # wrong_type: a command from the PMU
        data(8),
    ])


def wrapped(angle_rad):
    return np.remainder(np.asarray(angle_rad) + np.pi, 2 * np.pi) - np.pi
