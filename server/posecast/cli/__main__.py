from posecast.cli import main

raise SystemExit(main())
