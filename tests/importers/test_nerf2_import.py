"""`rfir import nerf2-ble`: NeRF2's BLE layout (gateway YAML, tx CSV, RSSI CSV with -100 = missing)."""
import numpy as np
import pytest

from rfir_core.artifacts import read_artifact
from rfir_core.errors import InputFileError
from rfir_stages.importers import import_nerf2_ble


@pytest.fixture
def ble_dir(tmp_path):
    folder = tmp_path / "ble"
    folder.mkdir()
    (folder / "gateway_position.yml").write_text("g1: [0.0, 0.0, 2.0]\ng2: [5.0, 0.0, 2.0]\n")
    (folder / "tx_pos.csv").write_text("x,y,z\n1,1,1\n2,2,1\n3,3,1\n")
    (folder / "gateway_rssi.csv").write_text("g1,g2\n-60,-70\n-100,-65\n-72,-100\n")
    (folder / "test_index.txt").write_text("2\n")
    (folder / "train_index.txt").write_text("0\n1\n")
    return folder


def test_links_skip_missing_rssi_and_keep_split(ble_dir, tmp_path):
    result = import_nerf2_ble(ble_dir, tmp_path / "m.h5", tx_power_dbm=4.0)
    art = read_artifact(result.path)
    assert result.links == 4
    np.testing.assert_array_equal(art["tx_id"], [0, 0, 1, 2])
    np.testing.assert_array_equal(art["rx_id"], [0, 1, 1, 0])
    np.testing.assert_allclose(art["path_gain_db"][:, 0], [-64, -74, -69, -76])
    np.testing.assert_array_equal(art["rx_pos"][1], [5, 0, 2])
    np.testing.assert_array_equal(art["split"], [0, 0, 0, 1])


def test_unknown_gateway_and_bad_cells(ble_dir, tmp_path):
    (ble_dir / "gateway_rssi.csv").write_text("g1,g9\n-60,-70\n-100,-65\n-72,-100\n")
    with pytest.raises(InputFileError, match="g9 missing from gateway_position.yml"):
        import_nerf2_ble(ble_dir, tmp_path / "m.h5")
    (ble_dir / "gateway_rssi.csv").write_text("g1,g2\n-60,-70\n-100,x\n-72,-100\n")
    with pytest.raises(InputFileError, match="line 3, column g2: 'x' is not a number"):
        import_nerf2_ble(ble_dir, tmp_path / "m.h5")
    assert not (tmp_path / "m.h5").exists()


def test_missing_file_and_millimetres(ble_dir, tmp_path):
    (ble_dir / "tx_pos.csv").write_text("x,y,z\n1000,1000,1000\n2000,2000,1000\n3000,3000,1000\n")
    with pytest.raises(InputFileError, match="millimetres"):
        import_nerf2_ble(ble_dir, tmp_path / "m.h5")
    (ble_dir / "tx_pos.csv").unlink()
    with pytest.raises(InputFileError, match="tx_pos.csv: file not found"):
        import_nerf2_ble(ble_dir, tmp_path / "m.h5")
