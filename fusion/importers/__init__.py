"""Built-in importers of ``fusion import`` (PX4 ULog, ArduPilot DataFlash, CSV by a mapping file),
registered as plugins of kind ``importer`` like any other: a third party adds a format the same way.
Each importer imports its reader library (pyulog, pymavlink) at first use, so start-up stays fast.
The decoder ``gps_fields`` reads the geodetic ``gps`` lines the importers write (fusion.importers.gps_decoder)."""
from fusion import hookimpl


@hookimpl
def fusion_register_components(registry):
    from fusion.importers.csvmap import CsvImporter
    from fusion.importers.dataflash import DataflashImporter
    from fusion.importers.gps_decoder import GpsFieldsDecoder
    from fusion.importers.ulog import UlogImporter

    registry.add(UlogImporter)
    registry.add(DataflashImporter)
    registry.add(CsvImporter)
    registry.add(GpsFieldsDecoder)
