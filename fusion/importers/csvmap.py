from fusion.api import Importer
class CsvImporter(Importer):
    name = "csv"
    suffixes = (".csv",)
