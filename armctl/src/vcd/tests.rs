//! The VCD reader against hand-written traces.

use super::*;

const HEADER: &str = "$date today $end\n$version test $end\n$timescale 1ns $end\n\
    $scope module arm $end\n$var wire 1 ! step0 $end\n$var wire 1 \" step1 $end\n\
    $var wire 1 ) dir0 $end\n$var wire 1 * dir1 $end\n$var real 64 A gripper_freq_hz $end\n\
    $var integer 32 B gripper_pulses $end\n$upscope $end\n$enddefinitions $end\n\
    #0\n$dumpvars\n0!\n0\"\n0)\n0*\nr0 A\nb0 B\n$end\n";

fn parse_text(body: &str) -> Result<Trace, VcdError> {
    parse(format!("{HEADER}{body}").as_bytes(), "test.vcd")
}

fn error_of(body: &str) -> VcdError {
    parse_text(body).expect_err("should not parse")
}

#[test]
fn rising_edges_count_with_direction() {
    // Joint 0: two steps up, one down. Joint 1: DIR low, two steps down; a STEP that
    // stays high is one edge.
    let trace = parse_text(
        "#5\n1)\n#10\n1!\n#12\n0!\n#20\n1!\n1\"\nr50 A\nb101 B\n#22\n0!\n1\"\n\
         #25\n0)\n#30\n1!\n0\"\n#31\n1\"\n#40\n",
    )
    .unwrap();
    assert_eq!(trace.positions(2), vec![1, -2]);
    assert_eq!(trace.joints[0].steps, 3);
    assert_eq!(trace.joints[1].steps, 2);
    assert_eq!(trace.end_tick, 40);
    assert!((trace.seconds_per_tick - 1e-9).abs() < 1e-24);
    assert_eq!(
        trace.joints[0].track.points(trace.end_tick),
        vec![
            (0, 0),
            (10, 0),
            (10, 1),
            (20, 1),
            (20, 2),
            (30, 2),
            (30, 1),
            (40, 1)
        ]
    );
    assert_eq!(
        trace.joints[1].track.points(trace.end_tick),
        vec![(0, 0), (20, 0), (20, -1), (31, -1), (31, -2), (40, -2)]
    );
    assert_eq!(trace.first_step_s(), Some(10e-9));
    assert!(trace.joints[1].declared && !trace.joints[2].declared);
}

#[test]
fn dir_set_at_the_same_time_as_the_step_counts() {
    // sim-host writes DIR before STEP within one time stamp.
    let trace = parse_text("#100\n1)\n1!\n#200\n0!\n0)\n#300\n1!\n").unwrap();
    assert_eq!(trace.positions(1), vec![0]);
    assert_eq!(trace.joints[0].steps, 2);
}

#[test]
fn x_and_z_are_low_and_aliases_follow_their_wire() {
    // One identifier declared as the STEP wire of joints 3 and 4; only joint 3 has DIR.
    let text = "$timescale 10 us $end\n$var wire 1 s step3 $end\n\
                $var wire 1 s step4 $end\n$var wire 1 d dir3 $end\n\
                $enddefinitions $end\n#0\nxs\n1d\n#1\n1s\n#2\nzs\n#3\n1s\n#4\n0s\n";
    let trace = parse(text.as_bytes(), "alias.vcd").unwrap();
    assert_eq!(trace.positions(5), vec![0, 0, 0, 2, -2]);
    assert!((trace.seconds_per_tick - 1e-5).abs() < 1e-18);
    let first = trace.first_step_s().unwrap();
    assert!((first - 1e-5).abs() < 1e-18, "{first}");
}

#[test]
fn a_long_trace_is_kept_in_few_buckets_with_the_exact_end() {
    let mut body = String::from("1)\n");
    // 100k steps up then 40k down, 1 us apart.
    let mut t = 0u64;
    for k in 0..140_000u64 {
        if k == 100_000 {
            body.push_str(&format!("#{}\n0)\n", t + 700));
        }
        t += 1000;
        body.push_str(&format!("#{t}\n1!\n#{}\n0!\n", t + 500));
    }
    let trace = parse_text(&body).unwrap();
    let joint = &trace.joints[0];
    assert_eq!(joint.position, 60_000);
    assert_eq!(joint.steps, 140_000);
    assert!(joint.track.buckets.len() as u64 <= TRACK_BUCKETS);
    assert!(joint.track.buckets.len() as u64 > TRACK_BUCKETS / 2);
    let points = joint.track.points(trace.end_tick);
    assert!(
        points.len() < 4 * TRACK_BUCKETS as usize,
        "{}",
        points.len()
    );
    assert_eq!(points.last(), Some(&(trace.end_tick, 60_000)));
    let peak = points.iter().map(|p| p.1).max();
    assert_eq!(peak, Some(100_000));
    // Time never goes back along the line.
    assert!(points.windows(2).all(|w| w[0].0 <= w[1].0));
}

#[test]
fn a_move_and_back_inside_one_bucket_keeps_its_peak() {
    let mut track = Track {
        width: 1000,
        buckets: Vec::new(),
    };
    track.step(10, 0, 1);
    track.step(20, 1, 2);
    track.step(30, 2, 1);
    track.step(40, 1, 0);
    assert_eq!(track.buckets.len(), 1);
    assert_eq!(
        track.points(50),
        vec![(0, 0), (10, 0), (25, 2), (40, 0), (50, 0)]
    );
}

#[test]
fn malformed_files_name_the_line_and_the_problem() {
    let header_lines = HEADER.lines().count();
    let cases = [
        ("#10\n1!\n#5\n", 3, "time goes back from #10 to #5"),
        ("#1\n1?\n", 2, "identifier `?` is not declared"),
        ("#abc\n", 1, "`#abc` is not a time"),
        ("#1\nhello\n", 2, "is not a time (#N) or a value change"),
        ("#1\n$var wire 1 q step4 $end\n", 2, "unexpected $var"),
        ("#1\n2!\n", 2, "is not a time (#N) or a value change"),
    ];
    for (body, line, problem) in cases {
        let error = error_of(body);
        assert_eq!(error.line, Some(header_lines + line), "{body:?}: {error}");
        assert!(error.problem.contains(problem), "{body:?}: {error}");
        assert!(error.to_string().starts_with("test.vcd:"), "{error}");
    }
    let error = error_of("#1\nb101");
    assert!(error.problem.contains("no identifier"), "{error}");
    assert_eq!(error.line, Some(header_lines + 2));

    let cut =
        parse(&b"$timescale 1ns $end\n$var wire 1 ! step0"[..], "cut.vcd").expect_err("cut short");
    assert_eq!(
        cut.to_string(),
        "cut.vcd:2: $var has no $end (file truncated?)"
    );
    let no_definitions = parse(&b"$var wire 1 ! step0 $end\n"[..], "a.vcd").unwrap_err();
    assert!(no_definitions.problem.contains("no $enddefinitions"));
    assert_eq!(no_definitions.line, None);
    let no_steps = parse(
        &b"$var wire 1 ! pin0 $end\n$enddefinitions $end\n#0\n1!\n"[..],
        "pins.vcd",
    )
    .unwrap_err();
    assert!(no_steps.problem.contains("no step0..step7"), "{no_steps}");
    let short_var = parse(&b"$var wire 1 ! $end\n"[..], "v.vcd").unwrap_err();
    assert_eq!(short_var.line, Some(1));
    assert!(short_var.problem.contains("$var needs"));
    let scale = parse(&b"$timescale 3 ns $end\n"[..], "s.vcd").unwrap_err();
    assert!(scale.problem.contains("$timescale `3 ns`"), "{scale}");
    let value_in_header = parse(&b"$var wire 1 ! step0 $end\n1!\n"[..], "h.vcd").unwrap_err();
    assert!(value_in_header.problem.contains("before $enddefinitions"));
    let binary = parse(&b"$comment \xff\xfe $end\n"[..], "bin.vcd").unwrap_err();
    assert!(binary.problem.contains("not UTF-8"), "{binary}");
    let missing = read(Path::new("/nonexistent/trace.vcd")).unwrap_err();
    assert!(missing.to_string().starts_with("/nonexistent/trace.vcd: "));
}

#[test]
fn vcd_is_recognised_by_its_first_word() {
    assert!(looks_like_vcd(b"\n  $date today $end"));
    assert!(!looks_like_vcd(b"time_s,state,j0\n0.1,2,5\n"));
    assert!(!looks_like_vcd(b""));
}
