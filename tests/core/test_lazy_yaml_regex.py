"""fusion.lazy_imports.cheap_yaml_reader: PyYAML's non-printable pattern, compiled from its ranges, matches
exactly the code points yaml's own spelling matches, and yaml's reader gets it when the CLI imports yaml."""
import re
import subprocess
import sys

from fusion import lazy_imports


def test_the_ranges_match_the_same_code_points_as_yaml_pattern():
    every = "".join(map(chr, range(0x110000)))            # surrogates included: a str can hold them
    theirs = [m.start() for m in re.compile(lazy_imports.YAML_NON_PRINTABLE).finditer(every)]
    mine = [m.start() for m in re.compile(lazy_imports.YAML_NON_PRINTABLE_RANGES).finditer(every)]
    assert mine == theirs
    assert len(mine) == 9 + 2 + 18 + 6 + 26 + 2048 + 2    # C0 but tab, LF, CR; DEL..U+9F but NEL; surrogates; FFFE-F


def test_yaml_spells_its_pattern_as_we_key_it_and_reads_as_before():
    code = ("from fusion.lazy_imports import cheap_yaml_reader, YAML_NON_PRINTABLE_RANGES as R, YAML_NON_PRINTABLE as Y\n"
            "cheap_yaml_reader()\n"
            "import yaml, yaml.reader, re\n"
            "p = yaml.reader.Reader.NON_PRINTABLE\n"
            "print(p.pattern == R, re.compile(Y) is p)\n"
            "try:\n    yaml.safe_load('a: b\\x07')\nexcept yaml.reader.ReaderError as e:\n    print(e.character == 7)\n"
            "print(yaml.safe_load('a: [1, \\u00e9]'))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split("\n")
    assert out[:3] == ["True True", "True", "{'a': [1, 'é']}"]


def test_nothing_changes_once_yaml_is_imported():
    code = ("import yaml.reader\nfrom fusion.lazy_imports import cheap_yaml_reader, YAML_NON_PRINTABLE as Y\n"
            "cheap_yaml_reader()\nprint(yaml.reader.Reader.NON_PRINTABLE.pattern == Y)\n")
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout == "True\n"
