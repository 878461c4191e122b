"""Navigation input (issue 15): several files merged, RINEX 2 GLONASS, RINEX 3 per-system
files, RINEX 4, Galileo and GLONASS records, blank fields, leap seconds, and compressed
files (gzip, Unix compress, zip, bzip2, Hatanaka) for both readers."""

import bz2
import doctest
import gzip
import math
import zipfile
from pathlib import Path

import hatanaka
import numpy as np
import pytest
import rinex_snippets as snip

from raimcore.sky import rinex
from raimcore.sky.rinex import RinexError, gps_minus_utc_s, gps_seconds, read_nav, read_obs

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
ESBC_NAV = DATA / "ESBC00DNK_R_20201770000_01D_MN.rnx"
ESBC_OBS = DATA / "ESBC00DNK_R_20201770000_02H_30S_MO.rnx"
#: How the reader's notes name the systems it reads (the default, "GCER").
READ = "systems read: GPS, BeiDou, Galileo, GLONASS"


def _nan(values) -> np.ndarray:
    return np.array([math.nan if v is None else v for v in values], dtype=float)


def _padded(values, width) -> np.ndarray:
    out = np.full(width, math.nan)
    out[:len(values)] = _nan(values)
    return out


def assert_same_records(a, b):
    """Two NavFiles hold the same records, kinds and order, system by system."""
    assert sorted(a.records) == sorted(b.records)
    for s in a.records:
        sa, ta, va = a.records[s]
        sb, tb, vb = b.records[s]
        assert sa.tolist() == sb.tolist(), s
        np.testing.assert_array_equal(ta, tb)
        np.testing.assert_array_equal(va, vb)  # NaN where NaN (assert_array_equal: equal)
        assert a.kinds[s].tolist() == b.kinds[s].tolist(), s


# -- blank fields, per-system files, duplicates --------------------------------------------

def test_blank_spare_beidou_record_is_kept_with_nan(tmp_path):
    n = read_nav(snip.nav_v3_system(tmp_path / "c.rnx", "C", blank_spare=True))
    sats, _, vals = n.records["C"]
    assert sats.tolist() == ["C05", "C23"]  # both kept
    assert np.isnan(vals[:, 20]).all()  # the blank spare
    assert np.isnan(vals[1, 22]) and np.isnan(vals[:, 29:]).all()  # blank trailing fields
    full = read_nav(snip.nav_v3_system(tmp_path / "c2.rnx", "C")).records["C"][2]
    np.testing.assert_array_equal(np.delete(vals, 20, axis=1), np.delete(full, 20, axis=1))
    assert full[:, 20].tolist() == [0.0, 0.0]
    assert n.notes == ()  # a blank spare is not worth a note


@pytest.mark.parametrize("split", [("G", "C"), ("C", "G"), ("G", "C", "E", "R")])
def test_per_system_files_merge_into_the_mixed_files_records(tmp_path, split):
    systems = "".join(sorted(split))
    mixed = read_nav(snip.nav_v3_system(tmp_path / "mixed.rnx", "GCER"), systems=systems)
    files = [snip.nav_v3_system(tmp_path / f"ESBC_{s}N.rnx", s) for s in split]
    merged = read_nav(files, systems=systems)
    assert_same_records(merged, mixed)
    assert merged.paths == tuple(str(f) for f in files) and merged.notes == ()
    for key in ("GPSA", "GPSB", "BDSA", "BDSB"):
        np.testing.assert_array_equal(merged.iono[key], mixed.iono[key])
    # Galileo's F/NAV and I/NAV records of the same toc are two messages, not duplicates.
    if "E" in split:
        assert merged.kinds["E"].tolist() == ["FNAV", "INAV"]


def test_the_old_single_path_call_still_works(tmp_path):
    path = snip.nav_v3_system(tmp_path / "m.rnx")
    one, listed = read_nav(path), read_nav([path])
    assert one.path == str(path) and one.paths == (str(path),)
    assert_same_records(one, listed)


def test_identical_duplicates_are_dropped_without_a_note(tmp_path):
    path = snip.nav_v3_system(tmp_path / "m.rnx")
    once = read_nav(path)
    twice = read_nav([path, snip.nav_v3_system(tmp_path / "copy.rnx", "GC")])
    assert_same_records(twice, once)
    assert twice.notes == ()


@pytest.mark.parametrize("changed_first", [False, True])
def test_duplicates_with_different_values_keep_the_first_and_say_so(tmp_path, changed_first):
    good = snip.nav_v3_system(tmp_path / "g.rnx", "G")
    bad = tmp_path / "g_other.rnx"
    af0 = f"{snip.GPS6[0]: .12e}"
    bad.write_text(good.read_text().replace(af0, f"{snip.GPS6[0] + 1e-9: .12e}", 1))
    n = read_nav([bad, good] if changed_first else [good, bad])
    sats, _, vals = n.records["G"]
    assert sats.tolist() == ["G06"]
    expected = snip.GPS6[0] + (1e-9 if changed_first else 0.0)
    assert vals[0, 0] == pytest.approx(expected, abs=1e-20)
    assert n.notes == ("G06: 1 duplicate record with different values (same toc and "
                       "message), kept the first",)


def test_skipped_systems_are_counted_in_a_note(tmp_path):
    n = read_nav(snip.nav_v3(tmp_path / "n.rnx"))  # G, R, E, S, C records
    assert sorted(n.records) == ["C", "E", "G", "R"]
    assert n.skipped == {"S": 1}
    assert n.notes == ("1 record of SBAS skipped (systems read: GPS, BeiDou, Galileo, GLONASS)",)
    assert read_nav(tmp_path / "n.rnx", systems="GRECJIS").notes == ()


@pytest.mark.parametrize("kwargs, word", [
    ({"paths": []}, "paths"),
    ({"paths": 5}, "paths"),
    ({"systems": "GX"}, "systems"),
    ({"systems": ""}, "systems"),
    ({"systems": "GG"}, "systems"),
    ({"systems": ["G"]}, "systems"),
])
def test_read_nav_refuses_bad_arguments_naming_them(tmp_path, kwargs, word):
    kwargs.setdefault("paths", snip.nav_v3(tmp_path / "n.rnx"))
    with pytest.raises(ValueError, match=f"^{word}: expected"):
        read_nav(**kwargs)


# -- RINEX 4 ---------------------------------------------------------------------------------

def test_rinex4_eph_records_equal_the_rinex3_records(tmp_path):
    v4 = read_nav(snip.nav_v4(tmp_path / "BRD400_MN.rnx"))
    v3 = read_nav(snip.nav_v3_system(tmp_path / "m.rnx"))
    assert_same_records(v4, v3)  # values, tocs and message kinds (D1/D2, INAV/FNAV)
    assert v4.version == 4.0 and v4.leap_s == 18.0
    assert v4.skipped == {"STO": 1, "EOP": 1, "ION C CNVX": 1, "G CNAV": 1, "C CNV1": 1,
                          "J": 1}
    assert set(v4.notes) == {"1 record of GPS CNAV skipped (message type not read)",
                             "1 record of BeiDou CNV1 skipped (message type not read)",
                             f"1 record of QZSS skipped ({READ})"}
    # Klobuchar from the ION records (the RINEX 3 header's values, more digits).
    for key in ("GPSA", "GPSB", "BDSA", "BDSB"):
        np.testing.assert_allclose(v4.iono[key], v3.iono[key], rtol=1e-3)
    np.testing.assert_allclose(v4.iono["GAL"][:3], [28.25, 7.8125e-03, 1.007080078125e-02])


def test_rinex4_reads_other_systems_and_message_lines_on_request(tmp_path):
    n = read_nav(snip.nav_v4(tmp_path / "a.rnx"), systems="J")
    assert n.records["J"][0].tolist() == ["J01"] and n.kinds["J"].tolist() == ["LNAV"]
    assert n.records["J"][2][0, 0] == pytest.approx(-2.819551154971e-04)
    assert n.skipped["G"] == 2 and n.skipped["C"] == 3  # LNAV + CNAV; D2 + D1 + CNV1


@pytest.mark.parametrize("edit, line, words", [
    (None, None, ["expected 5 lines after '> EPH R01 FDMA', got 4"]),
    (("> STO G06 LNAV", "> XYZ G06 LNAV"), 5, ["record type", "'XYZ'"]),
    (("> EPH C23 D1", "> EPH Y23 D1"), None, ["'Y23'"]),
    (("-9.687500000000e+01", "-9.6875000x0000e+01"), None, ["-9.6875000x0000e+01"]),
    (("    2020 06 25 00 00 00 GPUT", "> 2020 06 25 00 00 00 GPUT"), 6, ["record type"]),
])
def test_malformed_rinex4_files_name_file_and_line(tmp_path, edit, line, words):
    path = snip.nav_v4(tmp_path / "bad4.rnx", truncate=edit is None)
    if edit is not None:
        path.write_text(path.read_text().replace(*edit, 1))
    with pytest.raises(RinexError) as exc:
        read_nav(path)
    msg = str(exc.value)
    assert "bad4.rnx, line" in msg and "\n" not in msg
    assert all(w in msg for w in words), msg
    if line is not None:
        assert exc.value.line == line


# -- GLONASS and the leap seconds ------------------------------------------------------------

T_R01_UTC = gps_seconds(2020, 6, 25, 0, 15, 0)


@pytest.mark.parametrize("leap, gps_minus_utc", [("    18", 18.0), (None, 18.0),
                                                 ("    17", 17.0)])
def test_rinex2_glonass_toc_is_utc_plus_the_leap_seconds(tmp_path, leap, gps_minus_utc):
    n = read_nav(snip.nav_v2_glonass(tmp_path / "esbc1770.20g", leap=leap))
    sats, toc, vals = n.records["R"]
    assert sats.tolist() == ["R01"] and n.kinds["R"].tolist() == ["FDMA"]
    # The header is used when present (17 is deliberately wrong), else the table (18 s).
    assert toc[0] - T_R01_UTC == gps_minus_utc and n.leap_s == gps_minus_utc
    np.testing.assert_array_equal(vals[0], _padded(snip.R01[:15], 19))  # 4-line layout


def test_glonass_rinex2_and_rinex3_records_agree(tmp_path):
    v2 = read_nav(snip.nav_v2_glonass(tmp_path / "a.20g")).records["R"]
    v3 = read_nav(snip.nav_v3_system(tmp_path / "a_RN.rnx", "R")).records["R"]
    assert v2[1][0] == v3[1][0]
    np.testing.assert_array_equal(v2[2][0, :15], v3[2][0, :15])
    np.testing.assert_array_equal(v3[2][0], _nan(snip.R01))  # 3.05: 5th line read


def test_beidou_referenced_leap_seconds_header_is_converted(tmp_path):
    # RINEX 3.04: "LEAP SECONDS" may be BDT - UTC (4 s in 2020), marked BDS in 25-27.
    n = read_nav(snip.nav_v3_system(tmp_path / "r.rnx", "R",
                                    leap="     4     4  2111     4BDS"))
    assert n.leap_s == 18.0 and n.records["R"][1][0] - T_R01_UTC == 18.0


# GPS - UTC around leap seconds (IERS Bulletin C; USNO "leap seconds" table): each takes
# effect at 00:00:00 UTC, which is (new count) seconds later in GPS time.
@pytest.mark.parametrize("gps_date, expected", [
    ((1980, 1, 6, 0, 0, 0), 0.0),
    ((1981, 7, 1, 0, 0, 0), 0.0),  # still 1981-06-30 23:59:60 UTC
    ((1981, 7, 1, 0, 0, 1), 1.0),
    ((2006, 1, 1, 0, 0, 13), 13.0),  # 2005-12-31 23:59:60 UTC
    ((2006, 1, 1, 0, 0, 14), 14.0),
    ((2016, 12, 31, 12, 0, 0), 17.0),
    ((2017, 1, 1, 0, 0, 17), 17.0),
    ((2017, 1, 1, 0, 0, 18), 18.0),
    ((2020, 6, 25, 0, 0, 0), 18.0),
])
def test_gps_minus_utc_table(gps_date, expected):
    assert gps_minus_utc_s(gps_seconds(*gps_date)) == expected


def test_gps_minus_utc_batched_equals_scalar():
    t = gps_seconds(2015, 6, 30, 0, 0, 0) + np.arange(0.0, 3 * 86400.0, 3600.0).reshape(8, 9)
    out = gps_minus_utc_s(t)
    assert out.shape == (8, 9)
    assert [gps_minus_utc_s(float(x)) for x in t.ravel()] == out.ravel().tolist()
    assert set(out.ravel().tolist()) == {16.0, 17.0}


def test_rinex_docstring_examples_run():
    result = doctest.testmod(rinex)
    assert result.attempted > 0 and result.failed == 0


# -- the real ESBC navigation file -----------------------------------------------------------

@pytest.fixture(scope="module")
def esbc():
    if not ESBC_NAV.is_file():
        pytest.skip(f"{ESBC_NAV} not found (../shared/data is optional)")
    return read_nav(ESBC_NAV)


def _first_letters(path) -> dict[str, int]:
    """Records per system counted independently: lines after the header starting with a
    system letter."""
    lines = path.read_text().splitlines()
    body = lines[next(k for k, s in enumerate(lines) if "END OF HEADER" in s) + 1:]
    return {s: sum(line[:1] == s for line in body) for s in "GRECJS"}


def test_esbc_every_record_of_the_four_systems_is_read(esbc):
    count = _first_letters(ESBC_NAV)
    for s in "GREC":
        assert len(esbc.records[s][0]) == count[s], s
    assert esbc.notes == (f"{count['J']} records of QZSS skipped ({READ})",
                          f"{count['S']} records of SBAS skipped ({READ})")
    assert esbc.leap_s == 18.0


def test_esbc_galileo_records(esbc):
    sats, toc, vals = esbc.records["E"]
    # Galileo tocs are whole 10-minute marks of GST, taken as GPST.
    assert np.all(toc % 600.0 == 0.0)
    # The first E01 records are the snippet's F/NAV and I/NAV records.
    k = np.flatnonzero(sats == "E01")[:2]
    np.testing.assert_array_equal(vals[k[0]], _padded(snip.E01_FNAV, 31))
    np.testing.assert_array_equal(vals[k[1]], _padded(snip.E01_INAV, 31))
    assert toc[k[0]] == gps_seconds(2020, 6, 24, 23, 30, 0)
    # Kind from the data-source bits: F/NAV (bit 1) or I/NAV (bits 0, 2), both present.
    src = vals[:, 20].astype(int)
    assert np.all((esbc.kinds["E"] == "FNAV") == ((src & 2) != 0))
    assert set(esbc.kinds["E"].tolist()) == {"FNAV", "INAV"}
    # Semi-major axes: 29,600 km, E14/E18 on their 27,977 km eccentric orbits.
    a_m = vals[:, 10] ** 2
    assert np.all((a_m > 27.9e6) & (a_m < 29.7e6))


def test_esbc_glonass_records(esbc):
    sats, toc, vals = esbc.records["R"]
    # UTC(SU) quarter hours in the file, GPST here: 18 s later.
    assert np.all((toc - 18.0) % 900.0 == 0.0)
    k = np.flatnonzero((sats == "R01") & (toc == T_R01_UTC + 18.0))
    np.testing.assert_array_equal(vals[k[0]], _nan(snip.R01))
    # PZ-90 positions (km) on the 25,510 km orbits; frequency numbers -7..+6.
    r_m = np.linalg.norm(vals[:, [3, 7, 11]], axis=1) * 1e3
    assert np.all((r_m > 25.3e6) & (r_m < 25.7e6))
    freq = vals[:, 10]
    assert np.all((freq == np.round(freq)) & (freq >= -7) & (freq <= 6))


def test_esbc_merged_with_itself_is_unchanged(esbc):
    twice = read_nav([ESBC_NAV, ESBC_NAV])
    assert_same_records(twice, esbc)  # every record of the copy dropped, silently:
    assert twice.skipped == {k: 2 * v for k, v in esbc.skipped.items()}
    assert twice.notes == tuple(f"{2 * esbc.skipped[s]} records of {name} skipped ({READ})"
                                for s, name in (("J", "QZSS"), ("S", "SBAS")))


# -- compressed files --------------------------------------------------------------------------

def _compress(src: Path, how: str, tmp_path: Path) -> Path:
    """``src`` written compressed as ``how`` (the suffix it gets)."""
    raw = src.read_bytes()
    out = tmp_path / f"{src.stem}.{how}"
    if how == "gz":
        out.write_bytes(gzip.compress(raw))
    elif how == "bz2":
        out.write_bytes(bz2.compress(raw))
    elif how == "zip":
        with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z:
            z.writestr(src.name, raw)
    elif how == "Z":  # Unix compress only: hatanaka Hatanaka-compresses observations alone
        assert b"NAVIGATION DATA" in raw[:80]
        out.write_bytes(hatanaka.compress(raw, compression="Z"))
    else:  # Hatanaka by the package: "crx" / "yyd" alone, "crx.gz", "crx.Z", "yyd.Z"
        outer = how.split(".")[1] if "." in how else "none"
        out = tmp_path / f"{src.stem}.{how.replace('yyd', src.suffix[1:3] + 'd')}"
        out.write_bytes(hatanaka.compress(raw, compression=outer))
        inner = {"none": out.read_bytes, "gz": lambda: gzip.decompress(out.read_bytes())}
        if outer in inner:
            assert b"COMPACT RINEX" in inner[outer]()[:80]
    return out


def assert_same_obs(a, b):
    assert a.sat_names == b.sat_names and a.obs_types == b.obs_types
    assert a.version == b.version and a.events == b.events
    np.testing.assert_array_equal(a.t_gps_s, b.t_gps_s)
    np.testing.assert_array_equal(a.epoch_flag, b.epoch_flag)
    np.testing.assert_array_equal(a.approx_pos_ecef_m, b.approx_pos_ecef_m)
    assert sorted(a.codes) == sorted(b.codes)
    for code in a.codes:
        np.testing.assert_array_equal(a.codes[code], b.codes[code])


@pytest.mark.parametrize("how", ["gz", "bz2", "zip", "crx", "crx.gz", "crx.Z"])
def test_compressed_rinex3_obs_reads_the_same(tmp_path, how):
    plain = snip.obs_v3(tmp_path / "ESBC00DNK_R_20201770000_01H_30S_MO.rnx")
    packed = _compress(plain, how, tmp_path)
    assert packed.read_bytes() != plain.read_bytes()
    assert_same_obs(read_obs(packed), read_obs(plain))


@pytest.mark.parametrize("how", ["yyd", "yyd.Z", "gz"])
def test_compressed_rinex2_obs_reads_the_same(tmp_path, how):
    plain = snip.obs_v2(tmp_path / "slac1180.21o")
    packed = _compress(plain, how, tmp_path)
    assert_same_obs(read_obs(packed), read_obs(plain))


@pytest.mark.parametrize("how", ["gz", "Z", "zip"])
def test_compressed_navigation_files_read_the_same(tmp_path, how):
    plain = snip.nav_v4(tmp_path / "BRD400DLR_S_20201770000_01D_MN.rnx")
    packed = _compress(plain, how, tmp_path)
    assert_same_records(read_nav(packed), read_nav(plain))


def test_content_decides_not_the_name(tmp_path):
    plain = snip.obs_v3(tmp_path / "a.rnx")
    gz_named_rnx = tmp_path / "b.rnx"
    gz_named_rnx.write_bytes(gzip.compress(plain.read_bytes()))
    gz_named_z = tmp_path / "c.rnx.Z"  # archives do mislabel gzip as .Z
    gz_named_z.write_bytes(gzip.compress(plain.read_bytes()))
    plain_named_gz = tmp_path / "d.rnx.gz"  # already decompressed, name kept
    plain_named_gz.write_bytes(plain.read_bytes())
    for path in (gz_named_rnx, gz_named_z, plain_named_gz):
        assert_same_obs(read_obs(path), read_obs(plain))


def test_real_observations_through_hatanaka_crx_gz(tmp_path):
    if not ESBC_OBS.is_file():
        pytest.skip(f"{ESBC_OBS} not found (../shared/data is optional)")
    packed = tmp_path / "ESBC00DNK_R_20201770000_02H_30S_MO.crx.gz"
    packed.write_bytes(hatanaka.compress(ESBC_OBS.read_bytes(), compression="gz"))
    assert packed.stat().st_size < ESBC_OBS.stat().st_size / 4
    assert_same_obs(read_obs(packed), read_obs(ESBC_OBS))


def _corrupt(tmp_path: Path, kind: str) -> Path:
    plain = snip.obs_v3(tmp_path / "o.rnx").read_bytes()
    if kind == "truncated gzip":
        path, data = tmp_path / "o.rnx.gz", gzip.compress(plain)[:-40]
    elif kind == "damaged gzip":
        data = bytearray(gzip.compress(plain))
        data[30:60] = b"\xff" * 30
        path = tmp_path / "o.rnx.gz"
    elif kind == "text named .gz":
        path, data = tmp_path / "o.rnx.gz", b"404 Not Found\n"
    elif kind == "zip of two files":
        path = tmp_path / "o.zip"
        with zipfile.ZipFile(path, "w") as z:
            z.writestr("a.rnx", plain)
            z.writestr("b.rnx", plain)
        return path
    elif kind == "gzip of not RINEX":
        path, data = tmp_path / "notes.txt.gz", gzip.compress(b"shopping list\n" * 20)
    elif kind in ("truncated crx", "crx missing an epoch line"):
        crx = hatanaka.compress(plain, compression="none").decode().splitlines()
        assert crx[10].startswith("> 2020 06 25 00 00  0.0")  # the first epoch
        # Cut in the first epoch (CRX2RNX fails), or its epoch line lost (CRX2RNX warns
        # and skips the epoch).
        crx = crx[:13] if kind == "truncated crx" else crx[:10] + crx[12:]
        path, data = tmp_path / "o.crx", ("\n".join(crx) + "\n").encode()
    elif kind == "truncated Z":
        path, data = tmp_path / "o.rnx.Z", hatanaka.compress(plain, compression="Z")[:6]
    path.write_bytes(bytes(data))
    return path


@pytest.mark.parametrize("kind, words", [
    ("truncated gzip", ["gzip"]),
    ("damaged gzip", ["gzip"]),
    ("text named .gz", ["expected a gzip archive", "neither"]),
    ("zip of two files", ["holds 2", "a.rnx, b.rnx"]),
    ("gzip of not RINEX", ["line 1", "RINEX VERSION / TYPE"]),
    ("truncated crx", ["Compact RINEX", "truncated"]),
    ("crx missing an epoch line", ["Compact RINEX", "skip"]),
    ("truncated Z", ["Unix compress"]),
])
def test_corrupt_archives_give_one_line_naming_the_file(tmp_path, kind, words):
    path = _corrupt(tmp_path, kind)
    for reader in (read_obs, read_nav):
        with pytest.raises(RinexError) as exc:
            reader(path)
        msg = str(exc.value)
        assert msg.startswith(str(path)) and "\n" not in msg, msg
        assert all(w in msg for w in words), msg
