"""Bring real measurements into rfir: a plain CSV layout and NeRF2's BLE layout.

Both validate the whole input first and write nothing unless every row is valid.
"""
from .csv_links import CsvImportResult, import_csv, read_links_csv
from .nerf2_ble import import_nerf2_ble

__all__ = ["CsvImportResult", "import_csv", "import_nerf2_ble", "read_links_csv"]
