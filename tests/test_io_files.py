"""read_recording / write_recording: round trips and the documented errors on bad tables."""

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from hydrowatch.errors import DataError
from hydrowatch.io import read_recording, write_recording
from hydrowatch.recording import Recording


def make_recording(n=1000, state="healthy", t0=3.0, **extra_meta):
    rng = np.random.default_rng(7)
    t = t0 + np.arange(n) / 200.0
    channels = {
        "voltage": np.sin(t),
        "flow": 20 + rng.normal(size=n),
        "speed": 50 + rng.normal(size=n),
        "torque": 30 + rng.normal(size=n),
    }
    return Recording(t, channels, {"fleet": "f1", "machine": "m7", "state": state, **extra_meta})


def write_csv(path, header, rows):
    path.write_text(",".join(header) + "\n" + "\n".join(",".join(map(str, r)) for r in rows) + "\n")
    return path


def csv_rows(n=50, t0=0.0):
    return [[f"{t0 + i / 200:.3f}", 1.0, 2.0, 3.0, 4.0] for i in range(n)]


HEADER = ["t", "voltage", "flow", "speed", "torque"]


@pytest.mark.parametrize("suffix", [".mcap", ".parquet", ".csv"])
def test_round_trip_is_exact(tmp_path, suffix):
    rec = make_recording(state="valve_coil_warning", seed=42)
    rec.channels["temperature"] = np.linspace(40, 41, len(rec))
    back = read_recording(write_recording(rec, tmp_path / f"m7{suffix}"))
    assert len(back) == 1000
    for name in ["t", *rec.channels]:
        np.testing.assert_array_equal(back[name], rec[name])
    assert back.state == "valve_coil_warning"
    assert back.meta["source"].endswith(f"m7{suffix}")
    if suffix != ".csv":  # CSV keeps samples and label only
        assert (back.meta["fleet"], back.meta["machine"], back.meta["seed"]) == ("f1", "m7", 42)


def test_mcap_layout_follows_the_contract(tmp_path):
    from hydrowatch.io import summarize

    path = write_recording(make_recording(n=1000), tmp_path / "rec.mcap")
    info = summarize(path)
    assert info["finished"] and info["messages"] == 10  # 0.5 s chunks
    (channel,) = info["channels"]
    assert channel["topic"] == "hydro/f1/m7/sensors"
    assert channel["schema"] == "hydrowatch.sensor_chunk.v2"
    assert channel["message_encoding"] == "x-arrow-ipc-stream"
    assert channel["samples"] == 1000 and channel["t_s"] == [3.0, 3.0 + 999 / 200]
    meta = info["metadata"]["hydrowatch"]
    assert meta["state"] == "healthy" and meta["schema_version"] == "2" and '"torque": "N·m"' in meta["units"]
    assert info["log_time_ns"] == [3_000_000_000, 7_500_000_000]


def test_per_row_labels_survive_every_format(tmp_path):
    rec = make_recording(n=400)
    labels = np.array(["healthy"] * 200 + ["load_alert"] * 200, dtype=object)
    rec.meta.update(state=None, labels=labels)
    for suffix in (".mcap", ".parquet", ".csv"):
        back = read_recording(write_recording(rec, tmp_path / f"x{suffix}"))
        assert back.state is None
        assert list(back.meta["labels"][199:201]) == ["healthy", "load_alert"]


def test_csv_header_units_are_checked(tmp_path):
    ok = write_csv(
        tmp_path / "u.csv", ["t [s]", "voltage [V]", "flow [l/min]", "speed [rad/s]", "torque [Nm]"], csv_rows()
    )
    assert len(read_recording(ok)) == 50
    bad = write_csv(tmp_path / "b.csv", ["t", "voltage", "flow [bar]", "speed", "torque"], csv_rows())
    with pytest.raises(DataError, match=r"b.csv: column 'flow' must be in L/min. Got 'bar'"):
        read_recording(bad)


def test_csv_missing_column_names_it(tmp_path):
    path = write_csv(tmp_path / "m.csv", ["t", "flow", "speed"], [[r[0], *r[2:4]] for r in csv_rows()])
    with pytest.raises(DataError, match=r"m.csv: the command 'voltage' and at least one sensor .*Got no \['voltage'\]"
                                        r".*Add them \(units: voltage \[V\]\)"):
        read_recording(path)
    path = write_csv(tmp_path / "s.csv", ["t", "voltage", "temperature", "torque"], [[*r[:2], 40.0, ""]
                                                                                    for r in csv_rows()])
    with pytest.raises(DataError, match=r"s.csv: .*Got no \['one of flow, speed, torque'\]; the file has \['t', "
                                        r"'voltage', 'temperature'\]\. Add them \(units: flow \[L/min\], speed "
                                        r"\[rad/s\], torque \[N·m\]\)"):
        read_recording(path)  # an empty torque column is no torque sensor


@pytest.mark.parametrize("suffix", [".mcap", ".parquet", ".csv"])
@pytest.mark.parametrize("sensors", [("flow",), ("speed",), ("torque",), ("flow", "speed"), ("flow", "torque"),
                                     ("speed", "torque")])
def test_a_recording_of_any_sensor_subset_round_trips(tmp_path, suffix, sensors):
    full = make_recording()
    extra = {"temperature": np.linspace(40, 41, len(full)), "load_pressure": np.linspace(10, 20, len(full))}
    rec = Recording(full.t, {"voltage": full["voltage"], **{s: full[s] for s in sensors}, **extra}, full.meta)
    back = read_recording(write_recording(rec, tmp_path / f"r{suffix}"))
    assert sorted(back.channels) == sorted(["voltage", *sensors, *extra])
    for name, values in rec.channels.items():
        np.testing.assert_array_equal(back[name], values)


def test_csv_wrong_type_names_row(tmp_path):
    rows = csv_rows()
    rows[17][2] = "n/a!"
    with pytest.raises(DataError, match=r"column 'flow' must be numeric. Got 'n/a!' in row 17"):
        read_recording(write_csv(tmp_path / "w.csv", HEADER, rows))


def test_non_monotonic_time_names_row(tmp_path):
    rows = csv_rows()
    rows[30][0], rows[31][0] = rows[31][0], rows[30][0]
    with pytest.raises(DataError, match=r"strictly increasing. Got t=0.150000 s in row 31 after t=0.155000 s"):
        read_recording(write_csv(tmp_path / "n.csv", HEADER, rows))


def test_gap_reports_first_gap_row_and_size(tmp_path):
    rows = csv_rows(60)
    del rows[20:23]  # three samples missing before row 20
    with pytest.raises(DataError, match=r"Got a step of 20.000 ms before row 20 \(t=0.115000 s, about 3.0 samples"):
        read_recording(write_csv(tmp_path / "g.csv", HEADER, rows))


def test_nan_burst_reports_row_range(tmp_path):
    rec = make_recording(n=600)
    rec.channels["speed"][100:140] = np.nan
    rec.channels["speed"][500] = np.nan
    path = write_recording(rec, tmp_path / "nan.parquet")
    with pytest.raises(
        DataError, match=r"column 'speed' must have no NaN. Got NaN in rows 100-139 .*40 samples; 2 run"
    ):
        read_recording(path)


def test_optional_channel_all_empty_is_dropped(tmp_path):
    rows = [r + [""] for r in csv_rows()]
    back = read_recording(write_csv(tmp_path / "o.csv", [*HEADER, "temperature"], rows))
    assert "temperature" not in back.channels


def test_unknown_label_names_row(tmp_path):
    rows = [r + ["healthy" if i < 40 else "pump_leek_alert"] for i, r in enumerate(csv_rows())]
    with pytest.raises(DataError, match=r"health label in row 40 \(t=0.200 s\) must be .*Got 'pump_leek_alert'"):
        read_recording(write_csv(tmp_path / "l.csv", [*HEADER, "state"], rows))


def test_label_conflict_between_file_metadata_and_column(tmp_path):
    rec = make_recording(n=200)
    path = tmp_path / "c.parquet"
    write_recording(rec, path)
    table = pq.read_table(path)
    table = table.set_column(table.schema.get_field_index("state"), "state", pa.array(["load_alert"] * 200))
    pq.write_table(table, path)
    with pytest.raises(DataError, match="must agree with the file's label 'healthy'. Got 'load_alert'"):
        read_recording(path)


def test_parquet_string_column_is_a_type_error(tmp_path):
    table = pa.table(
        {
            "t": np.arange(10) / 200,
            "voltage": np.ones(10),
            "flow": ["x"] * 10,
            "speed": np.ones(10),
            "torque": np.ones(10),
        }
    )
    pq.write_table(table, tmp_path / "s.parquet")
    with pytest.raises(DataError, match="column 'flow' must be numeric. Got 'x' in row 0"):
        read_recording(tmp_path / "s.parquet")


def test_unsupported_suffix_and_unreadable_files(tmp_path):
    with pytest.raises(DataError, match=r"suffix must be one of .mcap, .parquet, .csv. Got '.txt'"):
        read_recording(tmp_path / "a.txt")
    (tmp_path / "junk.parquet").write_bytes(b"not parquet")
    with pytest.raises(DataError, match="junk.parquet: file must be a readable Parquet file"):
        read_recording(tmp_path / "junk.parquet")
    (tmp_path / "junk.mcap").write_bytes(b"not an mcap file at all")
    with pytest.raises(DataError, match="junk.mcap: file must be an MCAP file"):
        read_recording(tmp_path / "junk.mcap")


def test_training_reads_recordings_in_subfolders_and_passes_over_files_still_being_written(tmp_path, caplog):
    # the recorder's layout, <out>/<fleet>/<machine>/*.mcap, with one file it has not closed yet
    from hydrowatch.training.data import read_labelled

    for machine, state in (("m000", "healthy"), ("m001", "load_warning")):
        (tmp_path / "f1" / machine).mkdir(parents=True)
        write_recording(make_recording(state=state), tmp_path / "f1" / machine / "a.mcap")
    whole = (tmp_path / "f1" / "m000" / "a.mcap").read_bytes()
    (tmp_path / "f1" / "m000" / "b.mcap").write_bytes(whole[: len(whole) // 2])  # no closing bytes
    with pytest.raises(DataError, match="b.mcap"):
        read_labelled(tmp_path)
    caplog.clear()
    grouped = read_labelled(tmp_path, skip_unreadable=True)
    assert {state: len(runs) for state, runs in grouped.items()} == {"healthy": 1, "load_warning": 1}
    assert not [r for r in caplog.records if r.levelname == "WARNING"]
