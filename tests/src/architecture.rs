//! docs/ARCHITECTURE.md's crate graph is the workspace's: every edge the diagram draws
//! is a dependency in the crates' manifests and every dependency between the
//! workspace's crates is drawn, top to bottom (so no crate depends on one above it).
//! The materials layer stays free of the GPU stack and the command line's crates
//! however deep they would come in (read from `cargo metadata`).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn read_toml(path: &Path) -> toml::Table {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    text.parse()
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The diagram: the fenced block marked `crate-graph`, one crate a line with the
/// workspace crates it depends on after `->`, top to bottom.
fn diagram() -> Vec<(String, BTreeSet<String>)> {
    let path = root().join("docs/ARCHITECTURE.md");
    let text = std::fs::read_to_string(&path).expect("docs/ARCHITECTURE.md");
    let start = text
        .find("```crate-graph\n")
        .expect("a ```crate-graph block in docs/ARCHITECTURE.md");
    let body = &text[start + "```crate-graph\n".len()..];
    let body = &body[..body.find("```").expect("the block ends")];
    body.lines()
        .filter(|l| !l.trim().is_empty())
        .map(|line| {
            let (name, deps) = line.split_once("->").unwrap_or((line, ""));
            let deps = deps
                .split(|c: char| c.is_whitespace() || c == ',')
                .filter(|d| !d.is_empty())
                .map(str::to_string)
                .collect();
            (name.trim().to_string(), deps)
        })
        .collect()
}

/// Every workspace member's name and its normal dependencies (optional ones
/// included: a feature turns them on; dev-dependencies left out).
fn member_dependencies() -> BTreeMap<String, BTreeSet<String>> {
    let workspace = read_toml(&root().join("Cargo.toml"));
    let members = workspace["workspace"]["members"]
        .as_array()
        .expect("workspace members");
    let mut out = BTreeMap::new();
    for m in members {
        let dir = root().join(m.as_str().expect("member path"));
        let manifest = read_toml(&dir.join("Cargo.toml"));
        let name = manifest["package"]["name"]
            .as_str()
            .expect("name")
            .to_string();
        let mut tables: Vec<&toml::Table> = Vec::new();
        if let Some(d) = manifest.get("dependencies").and_then(|d| d.as_table()) {
            tables.push(d);
        }
        if let Some(targets) = manifest.get("target").and_then(|t| t.as_table()) {
            for t in targets.values() {
                if let Some(d) = t.get("dependencies").and_then(|d| d.as_table()) {
                    tables.push(d);
                }
            }
        }
        let deps = tables.iter().flat_map(|t| t.keys()).cloned().collect();
        out.insert(name, deps);
    }
    out
}

/// The workspace crates among each member's normal dependencies.
fn manifests() -> BTreeMap<String, BTreeSet<String>> {
    member_dependencies()
        .into_iter()
        .map(|(name, deps)| {
            let ours = deps
                .into_iter()
                .filter(|d| d.starts_with("meso-"))
                .collect();
            (name, ours)
        })
        .collect()
}

#[test]
fn the_diagram_is_the_crate_graph() {
    let drawn = diagram();
    let real = manifests();
    let drawn_names: BTreeSet<&String> = drawn.iter().map(|(n, _)| n).collect();
    let real_names: BTreeSet<&String> = real.keys().collect();
    assert_eq!(
        drawn_names, real_names,
        "the diagram's crates against the workspace's members"
    );
    for (i, (name, deps)) in drawn.iter().enumerate() {
        assert_eq!(
            deps, &real[name],
            "{name}: the diagram's edges against its Cargo.toml's dependencies"
        );
        let below: BTreeSet<&String> = drawn[i + 1..].iter().map(|(n, _)| n).collect();
        for d in deps {
            assert!(
                below.contains(d),
                "{name} -> {d} points up: the diagram lists crates top to bottom"
            );
        }
    }
}

/// Every package by name with the names of what it needs to build on this machine:
/// `cargo metadata`'s resolved graph for the host platform, normal and build edges
/// only (Cargo.lock alone would add dependencies under cfgs no build sets, such as
/// `cfg(bench)`, and the members' dev-dependencies).
fn build_graph() -> BTreeMap<String, Vec<String>> {
    let cargo = env!("CARGO");
    let rustc = Path::new(cargo).with_file_name("rustc");
    let rustc = if rustc.exists() {
        rustc
    } else {
        PathBuf::from("rustc")
    };
    let version = std::process::Command::new(&rustc)
        .arg("-vV")
        .output()
        .expect("rustc -vV runs");
    let version = String::from_utf8_lossy(&version.stdout);
    let host = version
        .lines()
        .find_map(|l| l.strip_prefix("host: "))
        .expect("rustc -vV names the host");
    let out = std::process::Command::new(cargo)
        .args(["metadata", "--format-version", "1", "--offline", "--locked"])
        .args(["--filter-platform", host])
        .current_dir(root())
        .output()
        .expect("cargo metadata runs");
    assert!(
        out.status.success(),
        "cargo metadata: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let meta: serde_json::Value = serde_json::from_slice(&out.stdout).expect("metadata JSON");
    let names: BTreeMap<&str, &str> = meta["packages"]
        .as_array()
        .expect("packages")
        .iter()
        .map(|p| {
            (
                p["id"].as_str().expect("id"),
                p["name"].as_str().expect("name"),
            )
        })
        .collect();
    let mut graph: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for node in meta["resolve"]["nodes"].as_array().expect("resolve nodes") {
        let name = names[node["id"].as_str().expect("node id")].to_string();
        let deps = node["deps"].as_array().expect("deps").iter().filter(|d| {
            d["dep_kinds"]
                .as_array()
                .expect("dep kinds")
                .iter()
                .any(|k| k["kind"].is_null() || k["kind"] == "build")
        });
        let deps = deps.map(|d| names[d["pkg"].as_str().expect("pkg")].to_string());
        graph.entry(name).or_default().extend(deps);
    }
    graph
}

fn reachable(graph: &BTreeMap<String, Vec<String>>, from: &str) -> BTreeSet<String> {
    let mut seen = BTreeSet::new();
    let mut stack = vec![from.to_string()];
    while let Some(n) = stack.pop() {
        if seen.insert(n.clone())
            && let Some(deps) = graph.get(&n)
        {
            stack.extend(deps.iter().cloned());
        }
    }
    seen
}

#[test]
fn the_materials_and_the_fit_need_no_gpu_and_no_command_line() {
    let graph = build_graph();
    for krate in ["meso-materials", "meso-fit"] {
        let all = reachable(&graph, krate);
        assert!(
            all.len() > 5,
            "{krate} reaches {} packages: lock read wrong",
            all.len()
        );
        for banned in ["wgpu", "clap", "anyhow", "eframe", "meso-render"] {
            assert!(!all.contains(banned), "{krate} depends on {banned}");
        }
    }
    // The render seam is below every device: no GPU stack either.
    let render = reachable(&graph, "meso-render");
    for banned in ["wgpu", "clap", "anyhow", "meso-modes"] {
        assert!(!render.contains(banned), "meso-render depends on {banned}");
    }
}
