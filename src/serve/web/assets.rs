//! The live view's files, compiled into the binary (dive sites have no internet):
//! the page and its script from `web/`, three.js from `web/vendor/three/` (see the
//! README there for where it came from).

/// One file the live view serves.
pub struct Asset {
    pub path: &'static str,
    pub content_type: &'static str,
    pub body: &'static str,
}

const JS: &str = "text/javascript; charset=utf-8";

pub const ASSETS: &[Asset] = &[
    Asset {
        path: "/",
        content_type: "text/html; charset=utf-8",
        body: include_str!("../../../web/index.html"),
    },
    Asset {
        path: "/app.js",
        content_type: JS,
        body: include_str!("../../../web/app.js"),
    },
    Asset {
        path: "/vendor/three/three.module.js",
        content_type: JS,
        body: include_str!("../../../web/vendor/three/three.module.js"),
    },
    Asset {
        path: "/vendor/three/three.core.js",
        content_type: JS,
        body: include_str!("../../../web/vendor/three/three.core.js"),
    },
    Asset {
        path: "/vendor/three/OrbitControls.js",
        content_type: JS,
        body: include_str!("../../../web/vendor/three/OrbitControls.js"),
    },
    Asset {
        path: "/vendor/three/LICENSE",
        content_type: "text/plain; charset=utf-8",
        body: include_str!("../../../web/vendor/three/LICENSE"),
    },
];

/// The file served at `path`, if any (`/index.html` is `/`).
pub fn find(path: &str) -> Option<&'static Asset> {
    let path = if path == "/index.html" { "/" } else { path };
    ASSETS.iter().find(|a| a.path == path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_page_finds_every_script_it_imports() {
        let page = find("/").expect("index");
        assert!(page.body.contains("/app.js"));
        let app = find("/app.js").expect("app.js");
        for import in ["three", "/vendor/three/OrbitControls.js"] {
            assert!(
                app.body.contains(&format!("from '{import}'")),
                "app.js imports {import}"
            );
        }
        assert!(page
            .body
            .contains("\"three\": \"/vendor/three/three.module.js\""));
        assert!(find("/vendor/three/three.module.js")
            .expect("three")
            .body
            .contains("from './three.core.js'"));
        assert!(find("/vendor/three/three.core.js").is_some());
        assert!(find("/nothing").is_none());
    }
}
