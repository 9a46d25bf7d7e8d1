from fusion.api import Importer
class DataflashImporter(Importer):
    name = "dataflash"
    suffixes = (".bin",)
