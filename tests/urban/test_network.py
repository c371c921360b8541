"""Networks with the real SUMO tools: unsignalized, routes enumerated, bad files refused in one line."""

import os
import re

import pytest

from models.urban.experiments import REAL_NET
from models.urban.network import UrbanInputError, artificial_network, enumerate_routes, junction_census, osm_network, sumo_network
from models.urban.sim import NetIndex

REPO_OSM = REAL_NET.parent / "monaco_network.osm.gz"


@pytest.mark.parametrize("n, roads, pairs", [(1, 8, 12), (2, 14, 30), (4, 24, 56)])
def test_artificial_networks_are_unsignalized_grids(tmp_path, n, roads, pairs):
    net = artificial_network(n, tmp_path / f"sc{n}.net.xml")
    census = junction_census(net)
    assert census.junctions == n  # Fig 4.2: 1, 2, 4 intersections
    assert census.traffic_lights == 0
    assert set(census.types) == {"right_before_left", "dead_end"}  # no priority junctions
    routes = enumerate_routes(net, 100, 0)
    assert len(routes) == pairs
    assert all(r["n_junctions"] >= 1 for r in routes)
    assert len({len(r["edges"].split()) for r in routes}) >= 1
    sampled = enumerate_routes(net, 5, 0)
    assert len(sampled) == min(5, pairs) and sampled == enumerate_routes(net, 5, 0)


def test_entry_roads_too_short_to_insert_a_vehicle_give_no_route(tmp_path):
    # 30 m arms leave 22.8 m entry roads after the junction's shape: SUMO inserts no bus there at the 10 m/s entry speed
    net = artificial_network(1, tmp_path / "short.net.xml", road_length_m=30.0)
    with pytest.raises(UrbanInputError, match=r"no route between entry roads of >= 35 m and exit roads"):
        enumerate_routes(net, 100, 0)


def test_bundled_real_network_loses_its_lights_and_priorities(tmp_path):
    net = sumo_network(REAL_NET, tmp_path / "real.net.xml", speed_mps=30.0)
    census = junction_census(net)
    assert census.traffic_lights == 0 and "traffic_light" not in census.types and "priority" not in census.types
    assert 60 <= census.junctions <= 120
    routes = enumerate_routes(net, 20, 0)
    assert len(routes) == 20 and max(r["n_junctions"] for r in routes) >= 3


def test_osm_extract_through_netconvert(tmp_path):
    net = osm_network(REPO_OSM, tmp_path / "monaco.net.xml")
    census = junction_census(net)
    assert census.junctions > 100 and census.traffic_lights == 0
    assert set(census.types) <= {"right_before_left", "dead_end"}


def test_bad_network_file_gives_one_clear_line(tmp_path):
    bad = tmp_path / "bad.net.xml"
    bad.write_text("<net><edge id='a' broken")
    with pytest.raises(UrbanInputError, match="bad.net.xml"):
        junction_census(bad)
    with pytest.raises(UrbanInputError, match="not found"):
        sumo_network(tmp_path / "missing.net.xml", tmp_path / "out.net.xml")
    with pytest.raises(UrbanInputError, match="not a gzip"):
        (tmp_path / "x.net.xml.gz").write_text("plain text")
        sumo_network(tmp_path / "x.net.xml.gz", tmp_path / "out.net.xml")
    notosm = tmp_path / "city.osm"
    notosm.write_text("not xml at all")
    with pytest.raises(UrbanInputError, match="city.osm: netconvert failed"):
        osm_network(notosm, tmp_path / "out.net.xml")


def test_a_network_replaced_by_rename_is_parsed_again(tmp_path, sc1_net):
    # the network's facts are parsed once per file version: a file replaced by rename within one clock tick and at the
    # same size is still a new version (its inode), not the cached old one
    net, text = tmp_path / "n.net.xml", sc1_net.read_text()
    net.write_text(text)
    lane, digit = re.search(r'<lane id="([^:"][^"]*)"[^>]* length="(\d)', text).groups()
    before = NetIndex(str(net)).lane_length[lane]
    new = tmp_path / "new.net.xml"
    new.write_text(re.sub(rf'(<lane id="{re.escape(lane)}"[^>]* length=")\d', rf"\g<1>{'2' if digit == '1' else '1'}", text, count=1))
    st = net.stat()
    os.replace(new, net)
    os.utime(net, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert net.stat().st_size == st.st_size and NetIndex(str(net)).lane_length[lane] != before
